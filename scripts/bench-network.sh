#!/usr/bin/env bash
# The network part of `make bench` (not a test): bass-bridge between two network namespaces
# made here (veth, fd00:ba55::/64, removed on exit; Zenoh scouting off, explicit endpoints).
# For 48-, 64-, 256- and 2205-frame chunks at 48 kHz stereo: capture->reader delay of a local
# reader of the source port vs a reader of the replica (p50/p99/p99.9), CPU of serve and mirror,
# bytes on the wire vs the raw audio rate, |clock offset estimate| (same machine: the true
# offset is 0) and the 1-minute load average at both ends of the row. Prints markdown tables
# (also to bench/network-results.md).
# Usage: scripts/bench-network.sh [SECONDS per row, default 20]
# Rows are CHUNK:N (N chunks per Zenoh message, `serve --chunks-per-message N`);
# BENCH_NET_CHUNKS="48:1 64:4" measures only those. Then bare Zenoh at the 48-frame message
# rate and size, 1 000 x 504 bytes a second (BENCH_NET_FLOOR_RATE / _BYTES; BENCH_NET_FLOOR=0
# skips it): the floor of the CPU goal. Then the goal of issue 37 item 5 and its verdict for
# the 48:1 row (p99 <= 1.0 ms, p99.9 <= 2 ms, every frame the replica reader missed named by
# a counter, serve + mirror CPU <= 1.2 x the floor), and the knob table (BENCH_NET_KNOBS=0
# skips it): the 48:1 row again with each of Zenoh's low-latency settings and ours, side by
# side, with and without BENCH_NET_LOAD_LOOPS (1) busy loops of the bench's own.
# Rates (CPU, wire bytes) are divided by the measured interval (timestamps taken with the
# counters at both of its ends), not by SECONDS: the readers' start-up and the clock sampler
# make the interval 1.1-1.2 x SECONDS.
# Then the Time table (BENCH_NET_TIME=0 skips it): every replica chunk's mapped stamp against
# the source's, clean and with asymmetric clock answers, and pylsl's time_correction() beside
# it (docs/time.md). Then two more tables:
# - recovery after link outages of BENCH_NET_OUTAGES seconds (default "15 60"; "" skips),
#   in the same namespaces (scripts/bench-net-recovery.py measures);
# - one robot serving BENCH_NET_FANOUT workstations (default 8; 0 skips) against one, peer to
#   peer and through a Zenoh router (BENCH_NET_ROUTER=0 skips the router rows), in namespaces
#   of its own: scripts/bench-net-fanout.sh.
# BENCH_NET_BIN=DIR runs the binaries in DIR without building.
# BENCH_NET_BASELINE=DIR also measures DIR/bass-bridge (an earlier build: serve and mirror
# both from DIR) in each row, right after the current one, labelled "(baseline)": before and
# after a change in one run, against one floor.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd); cd "$ROOT"
BIN=${CARGO_TARGET_DIR:-$ROOT/target}/release
SECS=${1:-20}
# Exactly make test-rust's build (same feature unification), so nothing is rebuilt after it.
# BENCH_NET_BIN=DIR: use the binaries in DIR (bass-bridge, bassd, examples/...) as they are.
if [ -n "${BENCH_NET_BIN:-}" ]; then BIN=$BENCH_NET_BIN; else
  make -C "$ROOT" --no-print-directory build-all; fi
export BENCH_NET_BIN=$BIN
[ -e "$BIN/libbassclient.so" ] && export BASS_LIB="$BIN/libbassclient.so"   # the recovery helper's library
# After issue 20 serve and mirror refuse a non-loopback endpoint without credentials: the
# bench runs them open (`--insecure`) when the binary has the option.
SERVE_X=(); MIRROR_X=()
[[ $("$BIN/bass-bridge" serve --help 2>&1) == *--insecure* ]] && SERVE_X=(--insecure)
[[ $("$BIN/bass-bridge" mirror --help 2>&1) == *--insecure* ]] && MIRROR_X=(--insecure)
NS_A=bnchA$$; NS_B=bnchB$$; WORK=$(mktemp -d /tmp/bass-bench-net.XXXXXX); PIDS=()
cleanup() { set +e; for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done; sleep 0.3
  ip netns del "$NS_A" 2>/dev/null; ip netns del "$NS_B" 2>/dev/null; rm -rf "$WORK"; }
trap cleanup EXIT; trap 'exit 1' TERM INT
ip netns add "$NS_A"; ip netns add "$NS_B"
ip link add vA netns "$NS_A" type veth peer name vB netns "$NS_B"
for n in "$NS_A" "$NS_B"; do ip -n "$n" link set lo up; done
# Keep the addresses while a link is down (the outage rows): without this a veth taken down
# loses its IPv6 addresses, and they do not come back with the link.
for n in "$NS_A" "$NS_B"; do ip netns exec "$n" sysctl -qw net.ipv6.conf.all.keep_addr_on_down=1; done
ip -n "$NS_A" addr add fd00:ba55::1/64 dev vA nodad; ip -n "$NS_B" addr add fd00:ba55::2/64 dev vB nodad
ip -n "$NS_A" link set vA up; ip -n "$NS_B" link set vB up
IN_A=(ip netns exec "$NS_A" env BASS_RUNTIME_DIR="$WORK/a"); IN_B=(ip netns exec "$NS_B" env BASS_RUNTIME_DIR="$WORK/b")
mkdir -p "$WORK/a" "$WORK/b"
EP="tcp/[fd00:ba55::1]:7447"
ticks() { awk '{print $14 + $15}' "/proc/$1/stat"; }
now() { date +%s.%N; }
# SIGTERM, then SIGKILL after 3 s: a bench never waits for a process without a bound.
stop() { local p; kill "$@" 2>/dev/null || true
  for p in "$@"; do for _ in $(seq 30); do kill -0 "$p" 2>/dev/null || break; sleep 0.1; done
    kill -0 "$p" 2>/dev/null && { echo "bench: pid $p ignored SIGTERM for 3 s: SIGKILL" >&2; kill -9 "$p" 2>/dev/null; }; done
  wait "$@" 2>/dev/null || true; }
HZ=$(getconf CLK_TCK)
OUT=bench/network-results.md
load1() { cut -d' ' -f1 /proc/loadavg; }
# One row: bassd (48 kHz stereo sim:pattern, NFPC-frame chunks, at SCHED_FIFO $B_RT, 0 = normal),
# serve and mirror of $BRIDGE with the extra options $SX / $MX (and ZENOH_RUNTIME=$ZRT when set),
# a local and a replica delay_reader (at SCHED_FIFO $R_RT when > 0) for SECS, with $LOAD busy
# loops (the bench's own load generator) running meanwhile. Appends one JSON line to
# $ROWS: delays, CPU, wire bytes, clock offsets, frame accounting, load average.
B_RT=0; R_RT=0; LOAD=0; ZRT=""; SX=(); MX=()
measure() {   # measure LABEL NFPC PER_MSG BRIDGE
  local label=$1 nfpc=$2 per_msg=$3 bridge=$4 ncop busy=() ld0 i
  ncop=$(( (48000 / 2 + nfpc - 1) / nfpc ))   # half a second on the port
  rm -f "$WORK/status.json"
  "${IN_A[@]}" "$BIN/bassd" --name src --rt-priority "$B_RT" --acquire sim:pattern --rate 48000 --frames "$nfpc" \
    --chunks $ncop --channels 2 >"$WORK/bassd.log" 2>&1 & BASSD=$!; PIDS+=($BASSD)
  "${IN_A[@]}" ${ZRT:+ZENOH_RUNTIME="$ZRT"} "$bridge" serve "${SERVE_X[@]}" --name src --listen "$EP" --no-scouting \
    --chunks-per-message "$per_msg" "${SX[@]}" >"$WORK/serve.log" 2>&1 & SERVE=$!; PIDS+=($SERVE)
  sleep 0.5
  "${IN_B[@]}" ${ZRT:+ZENOH_RUNTIME="$ZRT"} "$bridge" mirror "${MIRROR_X[@]}" --source src --name rep --connect "$EP" \
    --no-scouting --status-file "$WORK/status.json" "${MX[@]}" >"$WORK/mirror.log" 2>&1 & MIRROR=$!; PIDS+=($MIRROR)
  sleep 3
  for ((i = 0; i < LOAD; i++)); do timeout $((SECS + 4)) sh -c 'while :; do :; done' & busy+=($!); PIDS+=($!); done
  ld0=$(load1)
  T0=$(now); S0=$(ticks $SERVE); M0=$(ticks $MIRROR); B0=$(ip netns exec "$NS_B" cat /sys/class/net/vB/statistics/rx_bytes)
  "${IN_A[@]}" DELAY_READER_RT="$R_RT" "$BIN/examples/delay_reader" src "$SECS" >"$WORK/local.json" &
  L=$!
  ( for _ in $(seq "$SECS"); do sleep 1; python3 -c "import json;print(abs(json.load(open('$WORK/status.json'))['clock_offset_ns'] or 0))" 2>/dev/null; done ) >"$WORK/offsets" &
  O=$!
  "${IN_B[@]}" DELAY_READER_RT="$R_RT" "$BIN/examples/delay_reader" rep "$SECS" >"$WORK/remote.json" || echo '{}' >"$WORK/remote.json"
  wait $L $O || true
  S1=$(ticks $SERVE); M1=$(ticks $MIRROR); B1=$(ip netns exec "$NS_B" cat /sys/class/net/vB/statistics/rx_bytes); T1=$(now)
  sleep 1.2   # the mirror's next status write, with the counters of the measured interval
  python3 - "$WORK" "$label" "$nfpc" "$per_msg" "$T0" "$T1" "$HZ" "$S0" "$S1" "$M0" "$M1" "$B0" "$B1" "$ld0" "$(load1)" \
    >>"$ROWS" <<'PY'
import json, sys
w, label = sys.argv[1], sys.argv[2]
nfpc, per_msg, t0, t1, hz, s0, s1, m0, m1, b0, b1, ld0, ld1 = map(float, sys.argv[3:])
secs = t1 - t0   # the measured interval (~1.1 x SECONDS), not SECONDS
def js(p):
    try:
        return json.load(open(p))
    except (OSError, ValueError):
        return {}
loc, rem, st = js(f"{w}/local.json"), js(f"{w}/remote.json"), js(f"{w}/status.json")
offs = sorted(float(x) / 1e3 for x in open(f"{w}/offsets").read().split())
q = lambda v, p: v[round((len(v) - 1) * p)] if v else float("nan")
print(json.dumps({"label": label, "nfpc": int(nfpc), "per_msg": int(per_msg), "secs": secs,
    "local": loc, "replica": rem, "serve_cpu": 100 * (s1 - s0) / hz / secs, "mirror_cpu": 100 * (m1 - m0) / hz / secs,
    "wire": (b1 - b0) / (48000 * 2 * 4 * secs), "offset_p50": q(offs, 0.5), "offset_p99": q(offs, 0.99),
    "mirror_gap_frames": st.get("gap_frames_lost"), "load": [ld0, ld1]}))
print(f"row {label}: measured over {secs:.2f} s, load average {ld0:.2f} -> {ld1:.2f}", file=sys.stderr)
PY
  stop "${busy[@]}" $MIRROR $SERVE $BASSD
}
BRIDGES=("$BIN/bass-bridge"); [ -n "${BENCH_NET_BASELINE:-}" ] && BRIDGES+=("$BENCH_NET_BASELINE/bass-bridge")
: >"$WORK/rows.jsonl"; : >"$WORK/knobs.jsonl"; ROWS=$WORK/rows.jsonl
for ROW in ${BENCH_NET_CHUNKS:-48:1 64:1 64:4 256:1 2205:1}; do for BRIDGE in "${BRIDGES[@]}"; do
  LABEL="${ROW%:*}"; [ "${ROW#*:}" != 1 ] && LABEL+=", ${ROW#*:} per message"
  [ "$BRIDGE" != "$BIN/bass-bridge" ] && LABEL+=" (baseline)"
  measure "$LABEL" "${ROW%:*}" "${ROW#*:}" "$BRIDGE"
done; done
# The knob table (BENCH_NET_KNOBS=0 skips it): 48-frame chunks, one per message, with each of
# Zenoh's low-latency settings and ours, side by side in this run against the one floor below.
# serve's chunk publisher is always express, RealTime, CongestionControl::Drop (bass_bridge::net);
# the rows change the transport (a --zenoh-config on both sides), Zenoh's runtime sizing
# (ZENOH_RUNTIME), the scheduling (--rt-priority; bassd's and the readers'), and the load: the
# rows "+ load" run BENCH_NET_LOAD_LOOPS (1) busy loops of the bench's own beside them.
if [ "${BENCH_NET_KNOBS:-1}" = 1 ]; then
  ROWS=$WORK/knobs.jsonl
  zc() { echo "$2" >"$WORK/$1.json5"; echo "$WORK/$1.json5"; }
  NOBATCH=$(zc nobatch '{ transport: { link: { tx: { queue: { batching: { enabled: false } } } } } }')
  NOQOS=$(zc noqos '{ transport: { unicast: { qos: { enabled: false } } } }')
  LOWLAT=$(zc lowlat '{ transport: { unicast: { lowlatency: true, qos: { enabled: false } } } }')
  NL=${BENCH_NET_LOAD_LOOPS:-1}
  knob() { local label=$1; shift; local B_RT=0 R_RT=0 LOAD=0 ZRT="" SX=() MX=() a
    for a in "$@"; do case $a in
      zc=*) SX+=(--zenoh-config "${a#zc=}"); MX+=(--zenoh-config "${a#zc=}");;
      rt=*) SX+=(--rt-priority "${a#rt=}"); MX+=(--rt-priority "${a#rt=}");;
      zrt=*) ZRT=${a#zrt=};; brt=*) B_RT=${a#brt=};; rrt=*) R_RT=${a#rrt=};; load=*) LOAD=${a#load=};;
    esac; done
    measure "$label" 48 1 "$BIN/bass-bridge"; }
  knob "serve's settings: express, RealTime, Drop (qos on, adaptive batching on)"
  knob "+ load ($NL busy loop)" load=$NL
  knob "+ batching off" zc=$NOBATCH
  knob "qos off" zc=$NOQOS
  knob "lowlatency transport (qos off)" zc=$LOWLAT
  knob "ZENOH_RUNTIME rx: 1 worker thread (default 2)" "zrt=(rx:(worker_threads:1))"
  knob "ZENOH_RUNTIME tx: 2 worker threads (default 1)" "zrt=(tx:(worker_threads:2))"
  knob "serve, mirror --rt-priority 20" rt=20
  knob "--rt-priority 20 + lowlatency" rt=20 zc=$LOWLAT
  knob "all real-time: bassd 70, --rt-priority 20, readers 10" brt=70 rt=20 rrt=10
  knob "all real-time + load ($NL busy loop)" brt=70 rt=20 rrt=10 load=$NL
fi
# The floor: bare Zenoh (bridge/examples/zenoh_floor.rs, no bass) sending one message of a
# 48-frame chunk's size (120-byte header + 384 bytes of samples) 1 000 times a second, the
# message rate of 48-frame chunks, over the same veth, with the same scouting and publication
# settings: what one message per chunk costs before bass-bridge does anything.
FLOOR_RATE=${BENCH_NET_FLOOR_RATE:-1000}; FLOOR_BYTES=${BENCH_NET_FLOOR_BYTES:-504}
if [ "${BENCH_NET_FLOOR:-1}" = 1 ]; then
  "${IN_A[@]}" "$BIN/examples/zenoh_floor" pub "$EP" "$FLOOR_RATE" "$FLOOR_BYTES" $((SECS + 5)) >"$WORK/floor-pub.json" 2>&1 & FP=$!; PIDS+=($FP)
  sleep 0.5
  "${IN_B[@]}" "$BIN/examples/zenoh_floor" sub "$EP" $((SECS + 3)) >"$WORK/floor-sub.json" 2>&1 & FS=$!; PIDS+=($FS)
  sleep 2
  LD0=$(load1); T0=$(now); P0=$(ticks $FP); Q0=$(ticks $FS); B0=$(ip netns exec "$NS_B" cat /sys/class/net/vB/statistics/rx_bytes)
  sleep "$SECS"
  P1=$(ticks $FP); Q1=$(ticks $FS); B1=$(ip netns exec "$NS_B" cat /sys/class/net/vB/statistics/rx_bytes); T1=$(now)
  wait $FP $FS || true
  python3 - "$T0" "$T1" "$HZ" "$P0" "$P1" "$Q0" "$Q1" "$B0" "$B1" "$FLOOR_RATE" "$LD0" "$(load1)" >"$WORK/floor.json" <<'PY'
import json, sys
t0, t1, hz, p0, p1, q0, q1, b0, b1, rate, ld0, ld1 = map(float, sys.argv[1:])
secs = t1 - t0
print(json.dumps({"rate": rate, "pub_cpu": 100 * (p1 - p0) / hz / secs, "sub_cpu": 100 * (q1 - q0) / hz / secs,
                  "wire": (b1 - b0) / (48000 * 2 * 4 * secs), "load": [ld0, ld1]}))
PY
fi
# The table, the goal and its verdict (issue 37 item 5): capture -> replica reader at 48-frame
# (1 ms) chunks p99 <= 1.0 ms and p99.9 <= 2 ms, exact loss, serve + mirror CPU <= 1.2 x the floor.
python3 - "$WORK" tables >"$WORK/table" <<'PY'
import json, os, sys
w = sys.argv[1]
rows = [json.loads(l) for l in open(f"{w}/rows.jsonl") if l.strip()]
floor = json.load(open(f"{w}/floor.json")) if os.path.exists(f"{w}/floor.json") else None
d = lambda r, k: "{:.0f} / {:.0f} / {:.0f}".format(*(r.get(f"{p}_us", float("nan")) for p in ("p50", "p99", "p999"))) if r else "–"
print("| chunk | local p50/p99/p99.9 (us) | replica p50/p99/p99.9 (us) | serve CPU | mirror CPU | wire / raw | abs clock offset p50/p99 (us) | load avg |")
print("|---:|---:|---:|---:|---:|---:|---:|---:|")
for r in rows:
    print(f"| {r['label']} | {d(r['local'], 0)} | {d(r['replica'], 0)} | {r['serve_cpu']:.1f} % | {r['mirror_cpu']:.1f} % "
          f"| {r['wire']:.3f} | {r['offset_p50']:.1f} / {r['offset_p99']:.1f} | {r['load'][0]:.1f}-{r['load'][1]:.1f} |")
if floor:
    print(f"| 48-frame size, {floor['rate']:.0f}/s: bare Zenoh, no bass (publisher / subscriber) | – | – | {floor['pub_cpu']:.1f} % "
          f"| {floor['sub_cpu']:.1f} % | {floor['wire']:.3f} | – | {floor['load'][0]:.1f}-{floor['load'][1]:.1f} |")
fcpu = floor["pub_cpu"] + floor["sub_cpu"] if floor else float("nan")
def loss(r):
    """Frames the replica reader missed that no counter names (None: not known)."""
    x = r["replica"]
    if "span" not in x:
        return None
    unnamed = x["span"] - x["data"] - x["gap"] - x["lapped"]
    counted = r.get("mirror_gap_frames")
    if counted is not None and x["gap"] > counted:
        unnamed += x["gap"] - counted   # GAP frames the mirror's counter does not hold
    return unnamed
def goal(r):
    x = r["replica"]
    ratio = (r["serve_cpu"] + r["mirror_cpu"]) / fcpu
    checks = [("p99 <= 1.0 ms", x.get("p99_us", 1e9) <= 1000), ("p99.9 <= 2 ms", x.get("p999_us", 1e9) <= 2000),
              ("exact loss", loss(r) == 0), ("CPU <= 1.2 x floor", ratio <= 1.2)]
    missed = [n for n, ok in checks if not ok]
    return ratio, ("met" if not missed else "missed: " + ", ".join(missed))
goal_rows = [r for r in rows if r["nfpc"] == 48 and r["per_msg"] == 1 and "baseline" not in r["label"]]
print()
print("Goal (issue 37 item 5), 48-frame (1 ms) chunks, one per message: capture -> replica reader "
      "p99 <= 1.0 ms and p99.9 <= 2 ms, no frame lost that the counters do not name, serve + mirror "
      "CPU <= 1.2 x the bare-Zenoh floor at 1 000 messages/s.")
for r in goal_rows:
    x = r["replica"]
    ratio, v = goal(r)
    print(f"Verdict ({r['label']} frames): p99 {x.get('p99_us', float('nan')):.0f} us, p99.9 "
          f"{x.get('p999_us', float('nan')):.0f} us, frames lost unnamed {loss(r)} (GAP {x.get('gap')}, lapped "
          f"{x.get('lapped')}), CPU {r['serve_cpu'] + r['mirror_cpu']:.1f} % = {ratio:.2f} x the floor's {fcpu:.1f} %: {v}.")
knobs = [json.loads(l) for l in open(f"{w}/knobs.jsonl") if l.strip()]
if knobs:
    print()
    print("| 48-frame chunks, 1 per message: setting | replica p50/p99/p99.9 (us) | local p50/p99/p99.9 (us) "
          "| serve CPU | mirror CPU | serve + mirror / floor | frames lost unnamed | goal | load avg |")
    print("|---|---:|---:|---:|---:|---:|---:|---|---:|")
    for r in knobs:
        ratio, v = goal(r)
        print(f"| {r['label']} | {d(r['replica'], 0)} | {d(r['local'], 0)} | {r['serve_cpu']:.1f} % | {r['mirror_cpu']:.1f} % "
              f"| {ratio:.2f} x | {loss(r)} | {v} | {r['load'][0]:.1f}-{r['load'][1]:.1f} |")
PY
cat "$WORK/table" | tee "$OUT"

# Time (docs/time.md): the replica's mapped chunk stamps against the source's (one
# CLOCK_MONOTONIC in both namespaces: the source's stamp is the truth), 48-frame chunks, in
# the cases of BENCH_NET_TIME_CASES (default all), each with bass-bridge-faults' clock faults
# on serve's side (bridge/src/fault.rs):
#   clean   none (for clean, asym and jitter the "late" column sums up the chunks after 10 s);
#   asym    every clock answer held 600 us after its time was read (0 us one way, 600 the other);
#   jitter  every probe held 0-200 us before its time is read and its answer 0-200 us after;
#   drift   the source's clock 1 h ahead and 50 ppm fast (stamps and answers alike), run for
#           max(SECONDS, 60) + 10 s: the error after 60 s is the "late" column;
#   step    the source's CLOCK_REALTIME stamps stepped +1 s at 10 s (an NTP step): the mapped
#           stamps after it are the "late" column, the replica's wall-clock shift beside them;
# then pylsl's time_correction() between an outlet and an inlet in the same namespaces
# (liblsl over IPv6, unicast to the outlet's address). scripts/bench-time.py measures.
# BENCH_NET_TIME=0 skips it.
if [ "${BENCH_NET_TIME:-1}" = 1 ]; then
  {
  echo
  echo "| clock path | mapped-stamp error p50 / p99 / p99.9 / max (us) | chunks | truth inside the chunk's bound | bound p50 / p99 (us) | bound p50 / error p99 | first bound / first bound <= 100 us after (s) | late: after (s), error p99 / max (us), inside bound, wall-clock shift (ms) |"
  echo "|---|---:|---:|---:|---:|---:|---:|---|"
  } >>"$OUT"
  for CASE in ${BENCH_NET_TIME_CASES:-clean asym jitter drift step}; do
    T=$SECS; LATE=""
    case $CASE in
      clean) FAULT=""; LATE=10 ;;
      asym) FAULT=clock-delay=600; LATE=10 ;;
      jitter) FAULT=clock-jitter=200; LATE=10 ;;
      drift) FAULT=clock-offset=3600000000,clock-skew=50; T=$(( (SECS > 60 ? SECS : 60) + 10 )); LATE=60 ;;
      step) FAULT=realtime-step=1000:10; T=$(( SECS > 20 ? SECS : 20 )); LATE=12 ;;
      *) echo "bench-network: unknown time case $CASE (clean asym jitter drift step)" >&2; exit 2 ;;
    esac
    SERVE_CMD=("$BIN/bass-bridge" serve); [ -n "$FAULT" ] && SERVE_CMD=("$BIN/bass-bridge-faults" --fault "$FAULT" serve)
    rm -f "$WORK/status.json"
    "${IN_A[@]}" "$BIN/bassd" --name src --rt-priority 0 --acquire sim:pattern --rate 48000 --frames 48 \
      --chunks 1000 --channels 2 >"$WORK/bassd-time.log" 2>&1 & BASSD=$!; PIDS+=($BASSD)
    "${IN_A[@]}" "${SERVE_CMD[@]}" "${SERVE_X[@]}" --name src --listen "$EP" --no-scouting \
      >"$WORK/serve-time.log" 2>&1 & SERVE=$!; PIDS+=($SERVE)
    sleep 0.5
    "${IN_B[@]}" "$BIN/bass-bridge" mirror "${MIRROR_X[@]}" --source src --name rep --connect "$EP" --no-scouting \
      --status-file "$WORK/status.json" >"$WORK/mirror-time.log" 2>&1 & MIRROR=$!; PIDS+=($MIRROR)
    R=$(PYTHONPATH="$ROOT/python" python3 scripts/bench-time.py replica "$WORK/a" src "$WORK/b" rep "$WORK/status.json" "$T" $LATE) || R='{}'
    python3 - "$CASE" "$R" >>"$OUT" <<'PY'
import json, sys
case, r = sys.argv[1], json.loads(sys.argv[2] or "{}")
e, b = r.get("error_us") or {}, r.get("bound_us") or {}
f = lambda v: "–" if v is None else f"{v:.1f}"
n = r.get("chunks") or 0
cov = f"{100 * r.get('covered', 0) / n:.2f} %" if n else "–"
ratio = f"{b['p50'] / e['p99']:.2f}×" if b.get("p50") and e.get("p99") else "–"
label = {"clean": "bass mirror, clean", "asym": "bass mirror, clock answers 600 us late (asymmetric)",
         "jitter": "bass mirror, probes and answers jittered 0–200 us each way",
         "drift": "bass mirror, source clock 1 h ahead and 50 ppm fast",
         "step": "bass mirror, source CLOCK_REALTIME stepped +1 s at 10 s"}[case]
label += f" ({r.get('unbounded', 0)} chunks before the first clock map, stamped at arrival with no bound, left out)"
late = r.get("late")
if late:
    le, ls = late.get("error_us") or {}, late.get("realtime_shift_ms") or {}
    ln = le.get("n") or 0
    lcov = f"{100 * late.get('covered', 0) / ln:.2f} %" if ln else "–"
    shift = f"{f(ls.get('p50'))} (p50; max {f(ls.get('max'))})" if ls.get("n") else "–"
    late_cell = f"{late['after_s']:.0f}, {f(le.get('p99'))} / {f(le.get('max'))}, {lcov} of {ln}, {shift}"
else:
    late_cell = "–"
print(f"| {label} | {f(e.get('p50'))} / {f(e.get('p99'))} / {f(e.get('p999'))} / {f(e.get('max'))} | {n} | {cov} "
      f"| {f(b.get('p50'))} / {f(b.get('p99'))} | {ratio} | {f(r.get('first_bound_s'))} / {f(r.get('first_bound_100us_s'))} | {late_cell} |")
PY
    echo "time $CASE: $R" >&2
    stop $MIRROR $SERVE $BASSD
  done
  printf '[ports]\nIPv6 = force\n[multicast]\nResolveScope = link\n[lab]\nKnownPeers = {fd00:ba55::1}\n' >"$WORK/lsl_api.cfg"
  "${IN_A[@]}" LSLAPICFG="$WORK/lsl_api.cfg" python3 scripts/bench-time.py lsl-outlet bench-time $((SECS + 15)) \
    >"$WORK/lsl-outlet.log" 2>&1 & LO=$!; PIDS+=($LO)
  sleep 1
  R=$("${IN_B[@]}" LSLAPICFG="$WORK/lsl_api.cfg" timeout $((SECS + 30)) python3 scripts/bench-time.py lsl-inlet bench-time "$SECS") || R='{}'
  python3 - "$R" >>"$OUT" <<'PY'
import json, sys
r = json.loads(sys.argv[1] or "{}")
e = r.get("error_us") or {}
f = lambda v: "–" if v is None else f"{v:.1f}"
print(f"| pylsl time_correction(), clean (\\|offset\\|, 5 per second; LSL gives no per-sample bound) | {f(e.get('p50'))} / {f(e.get('p99'))} / {f(e.get('p999'))} / {f(e.get('max'))} | {e.get('n', 0)} corrections | – | – | – | {f(r.get('first_s'))} | – |")
PY
  echo "time lsl: $R" >&2
  stop $LO
  tail -n 5 "$OUT"
fi

# Recovery after a link outage: 480-frame chunks, the link taken down on the robot's side
# (`ip link set vA down`; the addresses stay, keep_addr_on_down above) for D seconds, then up;
# scripts/bench-net-recovery.py brings it up and measures, through the ports, the time until
# the replica's last_frame_index moves again and until it holds the frame that was the
# source's newest at link-up. At most BENCH_NET_RECOVERY_WAIT (30) s after link-up.
if [ -n "${BENCH_NET_OUTAGES-15 60}" ]; then
  WAIT_UP=${BENCH_NET_RECOVERY_WAIT:-30}
  {
  echo
  echo "| link outage | replica moving again after link-up | replica at the source's live edge | GAP frames counted | outages counted |"
  echo "|---:|---:|---:|---:|---:|"
  } >>"$OUT"
  for D in ${BENCH_NET_OUTAGES-15 60}; do
    rm -f "$WORK/status.json"
    "${IN_A[@]}" "$BIN/bassd" --name src --rt-priority 0 --acquire sim:pattern --rate 48000 --frames 480 \
      --chunks 50 --channels 2 >"$WORK/bassd-out$D.log" 2>&1 & BASSD=$!; PIDS+=($BASSD)
    "${IN_A[@]}" "$BIN/bass-bridge" serve "${SERVE_X[@]}" --name src --listen "$EP" --no-scouting \
      >"$WORK/serve-out$D.log" 2>&1 & SERVE=$!; PIDS+=($SERVE)
    sleep 0.5
    "${IN_B[@]}" "$BIN/bass-bridge" mirror "${MIRROR_X[@]}" --source src --name rep --connect "$EP" --no-scouting \
      --status-file "$WORK/status.json" >"$WORK/mirror-out$D.log" 2>&1 & MIRROR=$!; PIDS+=($MIRROR)
    sleep 4
    ip -n "$NS_A" link set vA down
    sleep "$D"
    R=$(python3 scripts/bench-net-recovery.py "$WORK/a" src "$WORK/b" rep "$WAIT_UP" -- \
      ip -n "$NS_A" link set vA up) || { R='{}'; ip -n "$NS_A" link set vA up || true; }
    sleep 1.5   # one more status-file write
    python3 - "$D" "$WAIT_UP" "$R" "$WORK/status.json" >>"$OUT" <<'PY'
import json, sys
d, wait, r, path = sys.argv[1], sys.argv[2], json.loads(sys.argv[3] or "{}"), sys.argv[4]
try:
    st = json.load(open(path))
except (OSError, ValueError):
    st = {}
f = lambda v: f"{v:.2f} s" if isinstance(v, (int, float)) else f"not within {wait} s"
print(f"| {d} s | {f(r.get('moved_s'))} | {f(r.get('live_s'))} | {st.get('gap_frames_lost', '–')} "
      f"| {st.get('outages', '–')} |")
PY
    echo "outage $D s: $R" >&2
    stop $MIRROR $SERVE $BASSD
  done
  tail -n $(( $(echo ${BENCH_NET_OUTAGES-15 60} | wc -w) + 3 )) "$OUT"
fi

# One robot, several workstations (own namespaces; appends to $OUT).
if [ "${BENCH_NET_FANOUT:-8}" -gt 0 ]; then
  scripts/bench-net-fanout.sh "$SECS" "${BENCH_NET_FANOUT:-8}" | tee -a "$OUT"
fi
