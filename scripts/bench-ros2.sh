#!/usr/bin/env bash
# The ROS 2 figures (not a test): `bass-bridge serve --ros2` between two network namespaces
# made here (veth, fd00:ba55::/64, removed on exit; Zenoh scouting off, explicit endpoints).
# For each chunk size (BENCH_ROS2_CHUNKS, default "480 64"; 48 kHz stereo) two runs of SECONDS:
#  - serve without --ros2, a mirror in the other namespace: serve's CPU, the replica's delay;
#  - serve --ros2, the same mirror, and a Zenoh subscriber of the ROS audio topic beside it:
#    serve's CPU, the replica's delay and the ROS topic's delay in the same run.
# Delay: from the capture of a chunk's last frame to the reader's wake-up (replica:
# bridge/examples/delay_reader, through the mapped clock) or to the ROS message's arrival in
# the subscriber's callback (Python eclipse-zenoh; CLOCK_REALTIME against header.stamp +
# (frames - 1) / rate: one clock, both namespaces on one machine).
# Prints a markdown table (also to bench/ros2-results.md).
# Usage: scripts/bench-ros2.sh [SECONDS, default 15]; BENCH_NET_BIN=DIR: binaries as they are.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd); cd "$ROOT"
BIN=${CARGO_TARGET_DIR:-$ROOT/target}/release
SECS=${1:-15}
if [ -n "${BENCH_NET_BIN:-}" ]; then BIN=$BENCH_NET_BIN; else
  make -C "$ROOT" --no-print-directory build-all; fi
NS_A=brosA$$; NS_B=brosB$$; WORK=$(mktemp -d /tmp/bass-bench-ros2.XXXXXX); PIDS=()
cleanup() { set +e; for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done; sleep 0.3
  ip netns del "$NS_A" 2>/dev/null; ip netns del "$NS_B" 2>/dev/null; rm -rf "$WORK"; }
trap cleanup EXIT; trap 'exit 1' TERM INT
ip netns add "$NS_A"; ip netns add "$NS_B"
ip link add vA netns "$NS_A" type veth peer name vB netns "$NS_B"
for n in "$NS_A" "$NS_B"; do ip -n "$n" link set lo up; done
ip -n "$NS_A" addr add fd00:ba55::1/64 dev vA nodad; ip -n "$NS_B" addr add fd00:ba55::2/64 dev vB nodad
ip -n "$NS_A" link set vA up; ip -n "$NS_B" link set vB up
mkdir -p "$WORK/a" "$WORK/b"
IN_A=(ip netns exec "$NS_A" env BASS_RUNTIME_DIR="$WORK/a"); IN_B=(ip netns exec "$NS_B" env BASS_RUNTIME_DIR="$WORK/b")
EP="tcp/[fd00:ba55::1]:7447"
ticks() { awk '{print $14 + $15}' "/proc/$1/stat"; }
now() { date +%s.%N; }
stop() { local p; kill "$@" 2>/dev/null || true
  for p in "$@"; do for _ in $(seq 30); do kill -0 "$p" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$p" 2>/dev/null || true; done; wait "$@" 2>/dev/null || true; }
HZ=$(getconf CLK_TCK)
OUT=bench/ros2-results.md
{
echo "| chunk | serve | serve CPU | replica delay p50/p99 (us) | ROS topic delay p50/p99 (us) | ROS messages received |"
echo "|---:|---|---:|---:|---:|---:|"
} >"$WORK/table"
for NFPC in ${BENCH_ROS2_CHUNKS:-480 64}; do for ROS in "" --ros2; do
  NCOP=$(( (48000 / 2 + NFPC - 1) / NFPC ))
  "${IN_A[@]}" "$BIN/bassd" --name src --rt-priority 0 --acquire sim:pattern --rate 48000 --frames $NFPC \
    --chunks $NCOP --channels 2 >"$WORK/bassd.log" 2>&1 & BASSD=$!; PIDS+=($BASSD)
  "${IN_A[@]}" "$BIN/bass-bridge" serve --insecure --name src --listen "$EP" --no-scouting $ROS \
    >"$WORK/serve.log" 2>&1 & SERVE=$!; PIDS+=($SERVE)
  sleep 0.5
  "${IN_B[@]}" "$BIN/bass-bridge" mirror --insecure --source src --name rep --connect "$EP" --no-scouting \
    >"$WORK/mirror.log" 2>&1 & MIRROR=$!; PIDS+=($MIRROR)
  echo '{}' >"$WORK/ros.json"
  if [ -n "$ROS" ]; then
    "${IN_B[@]}" timeout $((SECS + 20)) python3 - "$EP" $((SECS + 3)) >"$WORK/ros.json" <<'PY' & RS=$!
import json, struct, sys, time, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"peer"'); c.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
c.insert_json5("scouting/multicast/enabled", "false"); c.insert_json5("scouting/gossip/enabled", "false")
s = zenoh.open(c)
d = []
def on(x):
    now = time.time_ns()
    b = x.payload.to_bytes()
    sec, nsec, idlen = struct.unpack_from("<iII", b, 4)
    count_at = 4 + (12 + idlen + 3) // 4 * 4
    frames = struct.unpack_from("<I", b, count_at)[0] // 8
    d.append((now - (sec * 1_000_000_000 + nsec) - (frames - 1) * 1_000_000_000 // 48000) / 1e3)
sub = s.declare_subscriber("0/bass/src/audio/**", on)
time.sleep(3); d.clear(); time.sleep(float(sys.argv[2]) - 3)
v = sorted(d); q = lambda p: v[round((len(v) - 1) * p)] if v else float("nan")
print(json.dumps({"count": len(v), "p50_us": q(0.5), "p99_us": q(0.99)}))
PY
    PIDS+=($RS)
  fi
  sleep 3
  T0=$(now); S0=$(ticks $SERVE)
  "${IN_B[@]}" "$BIN/examples/delay_reader" rep "$SECS" >"$WORK/remote.json"
  S1=$(ticks $SERVE); T1=$(now)
  [ -n "$ROS" ] && { wait $RS || true; }
  python3 - "$WORK" "$NFPC" "${ROS:-(no --ros2)}" "$T0" "$T1" "$HZ" "$S0" "$S1" >>"$WORK/table" <<'PY'
import json, sys
w, nfpc, ros = sys.argv[1:4]
t0, t1, hz, s0, s1 = map(float, sys.argv[4:])
rem, r = json.load(open(f"{w}/remote.json")), json.load(open(f"{w}/ros.json"))
ros_d = f"{r['p50_us']:.0f} / {r['p99_us']:.0f}" if r.get("count") else "–"
print(f"| {nfpc} | {ros} | {100 * (s1 - s0) / hz / (t1 - t0):.1f} % | {rem['p50_us']:.0f} / {rem['p99_us']:.0f} "
      f"| {ros_d} | {r.get('count', '–')} |")
PY
  stop $MIRROR $SERVE $BASSD
done; done
tee "$OUT" <"$WORK/table"
