#!/usr/bin/env bash
# Checks `bass-bridge serve --ros2` with ROS 2 itself (docs/ros2.md): for a machine with
# ROS 2 Humble or Jazzy (or later) and rmw_zenoh_cpp. Not run by `make test`: the machines this
# project is built on have no ROS 2 (there the network suite checks the same layout with
# independent decoders, tests/bridge/cases/ros2.sh).
#
#   source /opt/ros/jazzy/setup.bash
#   export RMW_IMPLEMENTATION=rmw_zenoh_cpp
#   scripts/ros2-check.sh [--broker NAME] [--start] [--topic /bass/NAME/audio] [--node NAME]
#
# --broker NAME  the bass broker whose port is served (default: default)
# --start        start `bass-bridge serve --name NAME --ros2` here (connected to the local
#                Zenoh router, as ROS nodes are) and stop it at the end; without it a running
#                serve --ros2 is expected
# --topic, --node  as given to serve (defaults /bass/<broker>/audio, bass_bridge_<broker>)
#
# It starts rmw_zenohd if no Zenoh router listens on tcp/localhost:7447, then checks, with
# the ros2 command line: the node in `ros2 node list`; the three topics and their types in
# `ros2 topic list -t`; one AudioInfo from `ros2 topic echo --once` (TRANSIENT_LOCAL: it
# comes from the publisher's cache); one AudioDataStamped header; `ros2 topic hz` near
# rate / frames per chunk; chunk_info's publisher in `ros2 topic info`. Exit 0 when all held;
# otherwise each failure is named.
set -uo pipefail
BROKER=default; START=""; TOPIC=""; NODE=""
while (($#)); do
  case $1 in
    --broker) BROKER=$2; shift 2 ;;
    --start) START=1; shift ;;
    --topic) TOPIC=$2; shift 2 ;;
    --node) NODE=$2; shift 2 ;;
    -h|--help) sed -n '2,22p' "$0"; exit 0 ;;
    *) echo "ros2-check: unknown option $1 (--help)"; exit 2 ;;
  esac
done
# The ROS name of a broker name, as bass-bridge makes it (basskit::ros2::name_token).
TOKEN=$(python3 -c '
import re, sys
t = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9]", "_", sys.argv[1])).strip("_") or "bass"
print("b" + t if t[0].isdigit() else t)' "$BROKER")
TOPIC=${TOPIC:-/bass/$TOKEN/audio}; NODE=${NODE:-bass_bridge_$TOKEN}
INFO=${TOPIC}_info; CHUNKS=${TOPIC%/*}/chunk_info
FAILED=(); PIDS=()
ok() { echo "  ok: $*"; }
bad() { echo "  FAIL: $*"; FAILED+=("$*"); }
cleanup() { for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done; }
trap cleanup EXIT

command -v ros2 >/dev/null || { echo "ros2-check: no ros2 command: source /opt/ros/<distro>/setup.bash first"; exit 1; }
if [[ ${RMW_IMPLEMENTATION:-} != rmw_zenoh_cpp ]]; then
  echo "ros2-check: RMW_IMPLEMENTATION is '${RMW_IMPLEMENTATION:-}', not rmw_zenoh_cpp: export RMW_IMPLEMENTATION=rmw_zenoh_cpp"
  exit 1
fi
ros2 pkg prefix rmw_zenoh_cpp >/dev/null 2>&1 || { echo "ros2-check: rmw_zenoh_cpp is not installed (apt install ros-${ROS_DISTRO:-jazzy}-rmw-zenoh-cpp)"; exit 1; }
if ! ros2 interface show audio_common_msgs/msg/AudioDataStamped >/dev/null 2>&1; then
  echo "ros2-check: audio_common_msgs is not installed: ros2 cannot decode the audio topic"
  echo "  (install ros-${ROS_DISTRO:-jazzy}-audio-common-msgs, or build audio_common_msgs from ros-drivers/audio_common)"
  exit 1
fi
DISTRO=jazzy; [[ ${ROS_DISTRO:-} == humble ]] && DISTRO=humble
echo "ros2-check: ROS ${ROS_DISTRO:-?}, domain ${ROS_DOMAIN_ID:-0}, node /$NODE, topics $TOPIC $INFO $CHUNKS"

# A Zenoh router, as every rmw_zenoh node expects one on tcp/localhost:7447.
if ! (exec 3<>/dev/tcp/127.0.0.1/7447) 2>/dev/null; then
  echo "ros2-check: no Zenoh router on tcp/localhost:7447: starting rmw_zenohd"
  ros2 run rmw_zenoh_cpp rmw_zenohd >/tmp/ros2-check-rmw_zenohd.log 2>&1 & PIDS+=($!)
  for _ in $(seq 50); do (exec 3<>/dev/tcp/127.0.0.1/7447) 2>/dev/null && break; sleep 0.1; done
fi
if [[ -n $START ]]; then
  ARGS=(serve --name "$BROKER" --ros2 --ros2-distro "$DISTRO" --ros2-topic "$TOPIC" --ros2-node "$NODE"
        --connect tcp/localhost:7447 --listen 'tcp/localhost:0' --no-scouting)
  echo "ros2-check: bass-bridge ${ARGS[*]}"
  bass-bridge "${ARGS[@]}" >/tmp/ros2-check-serve.log 2>&1 & PIDS+=($!)
  sleep 2
  kill -0 "${PIDS[-1]}" 2>/dev/null || { echo "ros2-check: bass-bridge ended:"; tail -5 /tmp/ros2-check-serve.log; exit 1; }
fi

echo "== ros2 node list"
NODES=$(timeout 20 ros2 node list --no-daemon 2>&1)
grep -qx "/$NODE" <<<"$NODES" && ok "/$NODE is in the graph" || bad "/$NODE not in ros2 node list: $NODES"

echo "== ros2 topic list -t"
TOPICS=$(timeout 20 ros2 topic list -t --no-daemon 2>&1)
for want in "$TOPIC [audio_common_msgs/msg/AudioDataStamped]" "$INFO [audio_common_msgs/msg/AudioInfo]" \
            "$CHUNKS [bass_msgs/msg/ChunkInfo]"; do
  grep -qxF "$want" <<<"$TOPICS" && ok "$want" || bad "'$want' not in ros2 topic list -t: $TOPICS"
done

echo "== ros2 topic echo --once $INFO (TRANSIENT_LOCAL: from the publisher's cache)"
OUT=$(timeout 15 ros2 topic echo --once "$INFO" 2>&1)
if grep -q 'sample_format: S32LE' <<<"$OUT" && grep -q 'coding_format: wave' <<<"$OUT"; then
  ok "AudioInfo: $(tr '\n' ' ' <<<"$OUT")"
  RATE=$(awk '/^sample_rate:/ {print $2}' <<<"$OUT")
else bad "no AudioInfo from ros2 topic echo --once $INFO: $OUT"; RATE=""; fi

echo "== ros2 topic echo --once --no-arr $TOPIC"
OUT=$(timeout 15 ros2 topic echo --once --no-arr "$TOPIC" 2>&1)
SEC=$(awk '/sec:/ && !/nanosec/ {print $2; exit}' <<<"$OUT")
NOW=$(date +%s)
if [[ -n $SEC ]] && (( SEC > NOW - 60 && SEC < NOW + 60 )); then
  ok "AudioDataStamped with header.stamp.sec $SEC (now $NOW)"
else bad "no AudioDataStamped with a stamp near now from ros2 topic echo: $OUT"; fi

echo "== ros2 topic hz $TOPIC (8 s)"
HZ=$(timeout 8 ros2 topic hz "$TOPIC" 2>&1 | awk '/average rate:/ {r=$3} END {print r}')
FRAMES=$(timeout 15 ros2 topic echo --once --no-arr "$CHUNKS" 2>/dev/null | awk '/^frames:/ {print $2; exit}')
if [[ -z $HZ ]]; then bad "ros2 topic hz printed no rate"
elif [[ -n $RATE && -n $FRAMES ]]; then
  python3 -c "import sys; hz, want = float(sys.argv[1]), int(sys.argv[2]) / int(sys.argv[3]); sys.exit(abs(hz - want) > 0.1 * want)" \
    "$HZ" "$RATE" "$FRAMES" && ok "ros2 topic hz: $HZ Hz (rate $RATE / $FRAMES frames)" \
    || bad "ros2 topic hz: $HZ Hz, expected about $RATE / $FRAMES"
elif ros2 pkg prefix bass_msgs >/dev/null 2>&1; then
  bad "ros2 topic echo $CHUNKS decoded nothing although bass_msgs is installed (its type hash differs?)"
else ok "ros2 topic hz: $HZ Hz (chunk_info not decodable here: build bass_msgs from ros2/bass_msgs or /usr/share/bass/ros2/bass_msgs to compare the rate)"; fi

echo "== ros2 topic info $CHUNKS"
OUT=$(timeout 15 ros2 topic info "$CHUNKS" --no-daemon 2>&1)
grep -q 'Type: bass_msgs/msg/ChunkInfo' <<<"$OUT" && grep -q 'Publisher count: 1' <<<"$OUT" \
  && ok "chunk_info: one publisher of bass_msgs/msg/ChunkInfo" || bad "ros2 topic info $CHUNKS: $OUT"

if ((${#FAILED[@]})); then
  echo "ros2-check: ${#FAILED[@]} failed:"; printf '  FAIL: %s\n' "${FAILED[@]}"; exit 1
fi
echo "ros2-check: all checks passed"
