#!/usr/bin/env bash
# Part of `make bench` (scripts/bench-network.sh calls it; root; not a test): one robot
# serving N workstations against one, in one run. Network namespaces made here and removed
# on exit: the robot's, with a Linux bridge (fd00:ba55::1/64) to which one veth per
# workstation namespace (fd00:ba55::11, ::12, ...) and one for a LAN host (::10) are
# attached. Zenoh scouting off, explicit endpoints: nothing leaves these namespaces.
# 48 kHz stereo sim:pattern in BENCH_NET_FANOUT_CHUNK-frame chunks (default 480), 50 chunks
# on the port. Topologies:
# - peer to peer: every mirror connects to the robot's serve (the documented set-up);
# - through a Zenoh router on the LAN host (BENCH_NET_ROUTER=1, the default): there is no
#   zenohd here, so the router is a `bass-bridge serve --mode router` exporting nothing
#   (a broker name that does not exist, its own key namespace); serve and the mirrors are
#   its clients.
# For each: 1 workstation, then N (the first one kept), each measured over ~SECONDS:
# serve CPU (and the router's), mean mirror CPU, the robot's bytes sent / raw audio, and
# the capture->replica-reader delay (bridge/examples/delay_reader.rs in every workstation:
# the median of their p50, of their p99, and the largest p99). CPU and bytes are divided by
# the interval measured between the counter readings. All of it runs on one machine: with N
# workstations, N mirrors and N readers wake at each chunk on the same cores as serve.
# Usage: scripts/bench-net-fanout.sh [SECONDS, default 20] [N, default 8]
# Prints a markdown table.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd); cd "$ROOT"
BIN=${BENCH_NET_BIN:-${CARGO_TARGET_DIR:-$ROOT/target}/release}   # built by bench-network.sh
SECS=${1:-20}; N=${2:-8}; NFPC=${BENCH_NET_FANOUT_CHUNK:-480}
SERVE_X=(); MIRROR_X=()
[[ $("$BIN/bass-bridge" serve --help 2>&1) == *--insecure* ]] && SERVE_X=(--insecure)
[[ $("$BIN/bass-bridge" mirror --help 2>&1) == *--insecure* ]] && MIRROR_X=(--insecure)
NS_R=bnfR$$; NS_X=bnfX$$; WS=(); for i in $(seq "$N"); do WS+=("bnfW$$-$i"); done
WORK=$(mktemp -d /tmp/bass-bench-fanout.XXXXXX); PIDS=()
cleanup() { set +e; for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done; sleep 0.5
  for p in "${PIDS[@]}"; do kill -9 "$p" 2>/dev/null; done
  for n in "$NS_R" "$NS_X" "${WS[@]}"; do ip netns del "$n" 2>/dev/null; done
  if [ "${BENCH_NET_KEEP:-0}" = 1 ]; then echo "logs kept in $WORK" >&2; else rm -rf "$WORK"; fi; }
trap cleanup EXIT; trap 'exit 1' TERM INT
stop() { local p; kill "$@" 2>/dev/null || true
  for p in "$@"; do for _ in $(seq 30); do kill -0 "$p" 2>/dev/null || break; sleep 0.1; done
    kill -0 "$p" 2>/dev/null && { echo "bench: pid $p ignored SIGTERM for 3 s: SIGKILL" >&2; kill -9 "$p" 2>/dev/null; }; done
  wait "$@" 2>/dev/null || true; }

ip netns add "$NS_R"; ip -n "$NS_R" link set lo up
ip -n "$NS_R" link add br0 type bridge mcast_snooping 0
ip -n "$NS_R" addr add fd00:ba55::1/64 dev br0 nodad; ip -n "$NS_R" link set br0 up
HOSTS=("$NS_X" "${WS[@]}")
for i in "${!HOSTS[@]}"; do
  n=${HOSTS[$i]}
  ip netns add "$n"; ip -n "$n" link set lo up
  ip link add "p$i" netns "$NS_R" type veth peer name v0 netns "$n"
  ip -n "$NS_R" link set "p$i" master br0; ip -n "$NS_R" link set "p$i" up
  ip -n "$n" addr add "fd00:ba55::$((10 + i))/64" dev v0 nodad; ip -n "$n" link set v0 up
  mkdir -p "$WORK/$i"
done
mkdir -p "$WORK/r"
# exec: started with `&`, $! is then the process itself (its /proc/PID/stat is read).
in_ns() { local n=$1 d=$2; shift 2; exec ip netns exec "$n" env BASS_RUNTIME_DIR="$d" "$@"; }
ticks() { awk '{print $14 + $15}' "/proc/$1/stat" 2>/dev/null || { echo "bench: pid $1 is gone" >&2; echo 0; }; }
now() { date +%s.%N; }
txb() { ip netns exec "$NS_R" cat /sys/class/net/br0/statistics/tx_bytes; }
HZ=$(getconf CLK_TCK)

# measure LABEL K ROUTER_PID: K workstations read; SERVE and MIRRORS[] are running.
measure() {
  local label=$1 k=$2 router=${3:-} i t0 t1 s0 s1 x0=0 x1=0 m0=0 m1=0 b0 b1 rp=()
  sleep 4
  t0=$(now); b0=$(txb); s0=$(ticks "$SERVE"); if [ -n "$router" ]; then x0=$(ticks "$router"); fi
  for i in $(seq 0 $((k - 1))); do m0=$((m0 + $(ticks "${MIRRORS[$i]}"))); done
  for i in $(seq 1 "$k"); do
    in_ns "${HOSTS[$i]}" "$WORK/$i" "$BIN/examples/delay_reader" rep "$SECS" >"$WORK/delay$i.json" 2>/dev/null &
    rp+=($!)
  done
  wait "${rp[@]}" || true
  for i in $(seq 0 $((k - 1))); do m1=$((m1 + $(ticks "${MIRRORS[$i]}"))); done
  s1=$(ticks "$SERVE"); if [ -n "$router" ]; then x1=$(ticks "$router"); fi; b1=$(txb); t1=$(now)
  python3 - "$WORK" "$label" "$k" "$t0" "$t1" "$HZ" "$s0" "$s1" "$x0" "$x1" "$m0" "$m1" "$b0" "$b1" "$router" <<'PY'
import json, statistics, sys
w, label, k = sys.argv[1], sys.argv[2], int(sys.argv[3])
t0, t1, hz, s0, s1, x0, x1, m0, m1, b0, b1 = map(float, sys.argv[4:15])
router = sys.argv[15]
secs = t1 - t0
ds = []
for i in range(1, k + 1):
    try:
        ds.append(json.load(open(f"{w}/delay{i}.json")))
    except (OSError, ValueError):
        pass
ok = [d for d in ds if d.get("count", 0) > 0]
p50 = f"{statistics.median(d['p50_us'] for d in ok):.0f}" if ok else "–"
p99 = f"{statistics.median(d['p99_us'] for d in ok):.0f}" if ok else "–"
worst = f"{max(d['p99_us'] for d in ok):.0f}" if ok else "–"
cpu = lambda a, b: f"{100 * (b - a) / hz / secs:.1f} %"
rcpu = cpu(x0, x1) if router else "–"
raw = 48000 * 2 * 4 * secs
print(f"| {label} | {k} | {len(ok)} of {k} | {cpu(s0, s1)} | {rcpu} | {100 * (m1 - m0) / hz / secs / k:.1f} % "
      f"| {(b1 - b0) / raw:.2f} | {p50} / {p99} | {worst} |")
print(f"fanout {label} k={k}: interval {secs:.2f} s, readers {[d.get('count') for d in ds]}", file=sys.stderr)
PY
}

# run TOPOLOGY LABEL: bassd + serve on the robot, mirrors in the workstations, 1 then N.
run() {
  local topo=$1 label=$2 router="" ep i sconn=() mconn=()
  in_ns "$NS_R" "$WORK/r" "$BIN/bassd" --name src --rt-priority 0 --acquire sim:pattern --rate 48000 \
    --frames "$NFPC" --chunks 50 --channels 2 >"$WORK/bassd-$topo.log" 2>&1 & BASSD=$!; PIDS+=($BASSD)
  if [ "$topo" = p2p ]; then
    ep="tcp/[fd00:ba55::1]:7447"; sconn=(--listen "$ep"); mconn=(--connect "$ep")
  else
    ep="tcp/[fd00:ba55::10]:7447"
    in_ns "$NS_X" "$WORK/0" "$BIN/bass-bridge" serve "${SERVE_X[@]}" --mode router --name no-such-broker \
      --namespace bench-router --listen "$ep" --no-scouting >"$WORK/router.log" 2>&1 & router=$!; PIDS+=($router)
    sleep 0.5
    sconn=(--mode client --connect "$ep"); mconn=(--mode client --connect "$ep")
  fi
  in_ns "$NS_R" "$WORK/r" "$BIN/bass-bridge" serve "${SERVE_X[@]}" --name src "${sconn[@]}" --no-scouting \
    >"$WORK/serve-$topo.log" 2>&1 & SERVE=$!; PIDS+=($SERVE)
  sleep 0.5
  MIRRORS=()
  for i in $(seq 1 "$N"); do
    in_ns "${HOSTS[$i]}" "$WORK/$i" "$BIN/bass-bridge" mirror "${MIRROR_X[@]}" --source src --name rep \
      "${mconn[@]}" --no-scouting >"$WORK/mirror-$topo-$i.log" 2>&1 &
    MIRRORS+=($!); PIDS+=($!)
    if [ "$i" = 1 ]; then measure "$label" 1 "$router"; fi
  done
  if [ "$N" -gt 1 ]; then measure "$label" "$N" "$router"; fi
  stop "${MIRRORS[@]}" "$SERVE" "$BASSD" ${router:+"$router"}
}

echo
echo "| topology ($NFPC-frame chunks) | workstations | replicas read | serve CPU | router CPU | mirror CPU (each) | robot sent / raw | replica delay p50 / p99 (us) | worst reader's p99 (us) |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|"
run p2p "peer to peer"
if [ "${BENCH_NET_ROUTER:-1}" = 1 ]; then run router "router on a LAN host"; fi
