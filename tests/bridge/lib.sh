# Shared rig of the network suite (sourced by tests/bridge/cases/*.sh; docs/network.md).
#
# One case file = one process = its own two "computers": network namespaces made here,
# joined by a veth pair with IPv6 ULA addresses (fd00:ba55::/64), removed on exit even on
# failure. Every Zenoh process runs inside a namespace with multicast scouting and gossip off
# and explicit endpoints, so no packet leaves the namespaces. Readers are bounded by
# `timeout`, each case file by a watchdog (CASE_LIMIT seconds, default 300).
#
#   ns A (robot):       bassd --acquire sim:pattern   ->  bass-bridge serve
#   ns B (workstation): bass-bridge mirror  ->  replica port  ->  pattern_reader / Python
#
# A case file calls `rig_up`, runs its checks with `ok`/`bad`, and ends with `rig_done`
# (exit 0 only if nothing failed). Assertions are on counts and contents, never on timings.
set -euo pipefail
CASE=$(basename "${0%.sh}")
# The shell suites' rig: TOP, BIN, ok/bad and the verdict (summary), PIDS.
SUITE=$CASE
source "$(dirname "${BASH_SOURCE[0]}")/../lib.sh"
ROOT=$TOP
cd "$ROOT"
if [[ $(id -u) -ne 0 ]]; then echo "$CASE: needs root (network namespaces)"; exit 1; fi

# Short namespace names (unique per process); the veth ends keep fixed names inside them.
NS_A=bA$$; NS_B=bB$$; NS_C=bC$$
WORK=$(mktemp -d "/tmp/bass-bridge-$CASE.XXXXXX")
DIR_A=$WORK/a; DIR_B=$WORK/b; DIR_C=$WORK/c; mkdir -p "$DIR_A" "$DIR_B" "$DIR_C"
ADDR_A=fd00:ba55::1; ADDR_B=fd00:ba55::2; ADDR_C=fd00:ba55::3
EP="tcp/[$ADDR_A]:7447"
RATE=48000; NFPC=480; NCOP=50
# Open bridges in the rig (the suite's own namespaces): the security cases drop this.
INSECURE=(--insecure)
SERVE_BIN=()

rig_cleanup() {
  set +e
  for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done
  sleep 0.3
  for p in "${PIDS[@]}"; do kill -9 "$p" 2>/dev/null; done
  ip netns del "$NS_A" 2>/dev/null; ip netns del "$NS_B" 2>/dev/null; ip netns del "$NS_C" 2>/dev/null
  rm -rf "/etc/netns/$NS_B" "/etc/netns/$NS_C"
  if [[ -n ${BRIDGE_KEEP:-} ]]; then echo "$CASE: logs kept in $WORK"; else rm -rf "$WORK"; fi
}
trap rig_cleanup EXIT
# set -e ends a case at a failing command: say which, so a case never fails in silence.
trap 'echo "$CASE: stopped by a failing command at line $LINENO: $BASH_COMMAND"' ERR
trap 'echo "$CASE: stopped (watchdog or signal); failures so far: ${FAILED[*]:-none}"; rig_logs; exit 1' TERM INT
# The sleep keeps no descriptor of ours: a pipe reading this case ends when the case does.
( sleep "${CASE_LIMIT:-300}" </dev/null >/dev/null 2>&1; echo "$CASE: watchdog expired"; kill -TERM $$ ) 2>/dev/null & PIDS+=($!)

# rig_up [3]: namespaces A (robot) and B (workstation) joined by veth vA-vB
# (fd00:ba55::1, ::2); with 3, a third computer C (another workstation of the lab) joined
# to A by a second pair vA3-vC (A is fd00:ba57::1 there, C fd00:ba57::3).
rig_up() {
  ip netns add "$NS_A"; ip netns add "$NS_B"
  ip link add vA netns "$NS_A" type veth peer name vB netns "$NS_B"
  ip -n "$NS_A" link set lo up; ip -n "$NS_B" link set lo up
  # Keep the addresses while a link is down, as an unplugged cable would
  # (net.ipv6.conf.*.keep_addr_on_down; docs/network.md).
  ip netns exec "$NS_A" sysctl -qw net.ipv6.conf.all.keep_addr_on_down=1 net.ipv6.conf.vA.keep_addr_on_down=1
  ip netns exec "$NS_B" sysctl -qw net.ipv6.conf.all.keep_addr_on_down=1 net.ipv6.conf.vB.keep_addr_on_down=1
  ip -n "$NS_A" addr add $ADDR_A/64 dev vA nodad
  ip -n "$NS_B" addr add $ADDR_B/64 dev vB nodad
  ip -n "$NS_A" link set vA up; ip -n "$NS_B" link set vB up
  if [[ ${1:-2} == 3 ]]; then
    ip netns add "$NS_C"; ip -n "$NS_C" link set lo up
    ip link add vA3 netns "$NS_A" type veth peer name vC netns "$NS_C"
    ip netns exec "$NS_C" sysctl -qw net.ipv6.conf.all.keep_addr_on_down=1
    ip -n "$NS_A" addr add fd00:ba57::1/64 dev vA3 nodad
    ip -n "$NS_C" addr add fd00:ba57::3/64 dev vC nodad
    ip -n "$NS_A" link set vA3 up; ip -n "$NS_C" link set vC up
  fi
}

inA() { ip netns exec "$NS_A" env BASS_RUNTIME_DIR="$DIR_A" "$@"; }
inB() { ip netns exec "$NS_B" env BASS_RUNTIME_DIR="$DIR_B" "$@"; }
inC() { ip netns exec "$NS_C" env BASS_RUNTIME_DIR="$DIR_C" "$@"; }
# Daemons start through these arrays, not the functions: `ip netns exec` and `env` exec the
# program, so $! is the daemon itself and a kill reaches it.
IN_A=(ip netns exec "$NS_A" env BASS_RUNTIME_DIR="$DIR_A")
IN_B=(ip netns exec "$NS_B" env BASS_RUNTIME_DIR="$DIR_B")
IN_C=(ip netns exec "$NS_C" env BASS_RUNTIME_DIR="$DIR_C")

field() { python3 -c "import json,sys; print(json.loads(sys.argv[1])[sys.argv[2]])" "$1" "$2"; }
# status KEY [FILE]: a field of the mirror's status file.
status() { python3 -c "import json,sys; print(json.load(open(sys.argv[1]))[sys.argv[2]])" "${2:-$DIR_B/status.json}" "$1"; }

start_source() {
  "${IN_A[@]}" "$BIN/bassd" --name src --rt-priority 0 --acquire sim:pattern --rate $RATE \
    --frames $NFPC --chunks $NCOP --channels 2 >>"$WORK/bassd.log" 2>&1 &
  BASSD=$!; PIDS+=($BASSD)
}
# start_serve [OPTIONS]: serve in A on $EP. SERVE_BIN=(...) overrides the binary, e.g.
# SERVE_BIN=("$BIN/bass-bridge-faults" --fault drop=300) for the fault build.
start_serve() {
  "${IN_A[@]}" "${SERVE_BIN[@]:-$BIN/bass-bridge}" serve --name src --listen "$EP" --no-scouting "${INSECURE[@]}" "$@" \
    >>"$WORK/serve.log" 2>&1 &
  SERVE=$!; PIDS+=($SERVE)
}
# start_mirror [OPTIONS]: mirror in B, replica `rep`, status in $DIR_B/status.json.
start_mirror() {
  "${IN_B[@]}" "$BIN/bass-bridge" mirror --source src --name rep --connect "$EP" --no-scouting "${INSECURE[@]}" \
    --listen "tcp/[$ADDR_B]:0" --timeout 1 --status-file "$DIR_B/status.json" "$@" >>"$WORK/mirror.log" 2>&1 &
  MIRROR=$!; PIDS+=($MIRROR)
}
# reader FRAMES TIMEOUT_S [--from-first]: JSON line on stdout, exit code as pattern_reader's.
reader() { inB timeout $(( ${2%.*} + 5 )) "$BIN/examples/pattern_reader" rep "$@"; }
# wait_port DIR NAME [TRIES]: until the port file exists (0.1 s per try).
wait_port() {
  for _ in $(seq "${3:-100}"); do [[ -f $1/bass-$2.port ]] && return 0; sleep 0.1; done
  echo "port $2 never appeared in $1"; return 1
}
wait_replica() { wait_port "$DIR_B" rep || { rig_logs; return 1; }; }
# wait_for SECONDS COMMAND...: until COMMAND succeeds (0.1 s per try); 1 on expiry.
wait_for() {
  local end=$((SECONDS + $1)); shift
  until "$@" 2>/dev/null; do ((SECONDS < end)) || return 1; sleep 0.1; done
}
check_exact() { # JSON, label: no bad sample and exact accounting (the reader's exit code says it)
  local j=$1 what=$2
  if [[ $(field "$j" bad) == 0 ]] && (( $(field "$j" delivered) + $(field "$j" lost) + $(field "$j" gap) == $(field "$j" requested) )); then
    ok "$what: every sample right, exact accounting ($j)"
  else bad "$what: $j"; fi
}
rig_logs() {
  for f in "$WORK"/*.log; do [[ -f $f ]] && { echo "--- $(basename "$f")"; tail -25 "$f"; }; done
}
rig_done() {
  summary || { rig_logs; exit 1; }
  exit 0
}
# gone PID: the process has exited (a zombie not yet reaped counts as gone).
gone() { [[ ! -e /proc/$1 ]] || [[ $(awk '{print $3}' "/proc/$1/stat" 2>/dev/null) == Z ]]; }
# term_ms PID: sends SIGTERM, prints how many ms the process took to exit (or "never" in 3 s).
term_ms() {
  local t0 t1; kill -TERM "$1" 2>/dev/null; t0=$(date +%s%N)
  if wait_for 3 gone "$1"; then t1=$(date +%s%N); echo $(( (t1 - t0) / 1000000 )); else echo never; fi
}
