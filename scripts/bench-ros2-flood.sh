#!/usr/bin/env bash
# What a flood of history queries on the latched audio_info topic costs `serve --ros2` (not a
# test): serve's CPU (utime + stime from /proc/PID/stat) for SECONDS idle, then for SECONDS
# while an authenticated workstation (tests/bridge/ros2_peer.py flood: PyPI eclipse-zenoh,
# TRANSIENT_LOCAL history queries `<audio_info key>/@adv/**?_max=1`, sent without waiting for
# answers) floods it, in two network namespaces made here (veth, fd00:ba55::/64, removed on
# exit; scouting off). serve answers at most bass_bridge::ros2::latched's BURST + RATE/s and
# withdraws its history queryable when over that, so a peer (as rmw_zenoh's nodes are) stops
# sending; a Zenoh *client* of serve itself sends every query to serve regardless (Zenoh's
# handling of each, unanswered, is then the cost: BENCH_FLOOD_MODE=client shows it).
# Prints a markdown table: serve, flooder mode, idle CPU, flood CPU, ratio, queries, answers.
# Usage: scripts/bench-ros2-flood.sh [SECONDS, default 10]
#   BENCH_NET_BIN=DIR: binaries as they are (no build); BENCH_FLOOD_SERVE=FILE: another
#   bass-bridge for serve (e.g. one built from an older commit, for a before/after);
#   BENCH_FLOOD_MODE=peer (default) or client: the flooder's Zenoh mode.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd); cd "$ROOT"
BIN=${CARGO_TARGET_DIR:-$ROOT/target}/release
SECS=${1:-10}
if [ -n "${BENCH_NET_BIN:-}" ]; then BIN=$BENCH_NET_BIN; else
  make -C "$ROOT" --no-print-directory build-all; fi
SERVE_BIN=${BENCH_FLOOD_SERVE:-$BIN/bass-bridge}
MODE=${BENCH_FLOOD_MODE:-peer}
NS_A=bflA$$; NS_B=bflB$$; WORK=$(mktemp -d /tmp/bass-bench-flood.XXXXXX); PIDS=()
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
C=$WORK/cred; mkdir -p "$C"
"$BIN/bass-bridge" credentials "$C/robot.cred" --user robot 2>/dev/null
"$BIN/bass-bridge" credentials "$C/ws2.cred" --user ws2 --trust "$C/robot.pub" 2>/dev/null
"$BIN/bass-bridge" credentials "$C/robot.cred" --trust "$C/ws2.pub" 2>/dev/null
PW=$("$BIN/bass-bridge-faults" --print-pair-password "$C/ws2.cred" ws2 robot)
ticks() { awk '{print $14 + $15}' "/proc/$1/stat"; }
now() { date +%s.%N; }
pct() { python3 -c "import sys; t0,t1,s0,s1,hz=map(float,sys.argv[1:]); print(f'{100*(s1-s0)/hz/(t1-t0):.1f}')" "$@"; }
HZ=$(getconf CLK_TCK)
"${IN_A[@]}" "$BIN/bassd" --name src --rt-priority 0 --acquire sim:pattern --rate 48000 --frames 480 \
  --chunks 50 --channels 2 >"$WORK/bassd.log" 2>&1 & PIDS+=($!)
sleep 0.5
"${IN_A[@]}" "$SERVE_BIN" serve --name src --listen "$EP" --no-scouting --credentials "$C/robot.cred" --ros2 \
  >"$WORK/serve.log" 2>&1 & SERVE=$!; PIDS+=($SERVE)
sleep 3
T0=$(now); S0=$(ticks $SERVE); sleep "$SECS"; S1=$(ticks $SERVE); T1=$(now)
IDLE=$(pct "$T0" "$T1" "$S0" "$S1" "$HZ")
"${IN_B[@]}" ROS2_PEER_MODE="$MODE" timeout $((SECS + 30)) python3 tests/bridge/ros2_peer.py flood "$EP" ws2 "$PW" src $((SECS + 2)) \
  >"$WORK/flood.json" & FL=$!; PIDS+=($FL)
sleep 1.5   # the flooder's session comes up (it floods SECONDS + 2 s)
T0=$(now); S0=$(ticks $SERVE); sleep "$SECS"; S1=$(ticks $SERVE); T1=$(now)
FLOOD=$(pct "$T0" "$T1" "$S0" "$S1" "$HZ")
wait $FL || true
python3 - "$SERVE_BIN $MODE" "$IDLE" "$FLOOD" "$WORK/flood.json" <<'PY'
import json, sys
b, idle, flood, f = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), json.load(open(sys.argv[4]))
print("| serve, flooder | idle CPU | CPU under the flood | ratio | queries sent | answered |")
print("|---|---:|---:|---:|---:|---:|")
print(f"| {b} | {idle:.1f} % | {flood:.1f} % | {flood / idle:.2f} | {f['queries']} | {f['replies']} |")
PY
