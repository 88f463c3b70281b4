#!/usr/bin/env bash
# Network case "ros2": `bass-bridge serve --ros2` as a ROS 2 node on rmw_zenoh's layout, read
# in the other namespace by a subscriber that shares no code with bass
# (tests/bridge/ros2_subscriber.py: PyPI eclipse-zenoh on the key expressions it builds from
# rmw_zenoh's documented grammar, rosbags computing the RIHS01 hashes and deserialising every
# CDR payload):
#  1. peer to peer, beside a mirror: the graph's liveliness tokens (node and three publishers,
#     their QoS), every audio sample against the pattern, the companion topic's frame indices
#     contiguous with no loss, consecutive sequence numbers in the attachments, the latched
#     AudioInfo from the publisher's cache; the replica exact at the same time;
#  2. through a Zenoh router (as with rmw_zenohd), serve in client mode, ROS_DOMAIN_ID=7, a
#     topic and node of the user's, the subscriber a peer of the router only;
#  3. the Humble layout (TypeHashNotSupported), a bad topic refused (exit 2), SIGTERM: the
#     node leaves the graph (its tokens gone) within a second.
# tests/bridge/lib.sh has the rig.
source "$(dirname "$0")/../lib.sh"
rig_up
SECS=3
zid_of() { grep -m1 -o 'Zenoh session open zid=[0-9a-f]*' "$1" | cut -d= -f2 || true; }
sub() { # ENDPOINT MODE ZID DOMAIN NODE TOPIC: the subscriber's JSON line; its exit code
  inB timeout 60 python3 tests/bridge/ros2_subscriber.py "$@" $SECS 2 $RATE
}

echo "== 0. the bass_msgs ROS package (ros2/bass_msgs), read by ROS's own package parser"
if P=$(python3 - <<'PY' 2>&1
from catkin_pkg.package import parse_package
from rosbags.typesys import get_types_from_msg
p = parse_package("ros2/bass_msgs")
p.validate()
assert p.package_format == 3 and p.name == "bass_msgs", (p.package_format, p.name)
assert "rosidl_interface_packages" in [g.name for g in p.member_of_groups], p.member_of_groups
assert "std_msgs" in [d.name for d in p.build_depends] and "std_msgs" in [d.name for d in p.exec_depends]
cmake = open("ros2/bass_msgs/CMakeLists.txt").read()
assert '"msg/ChunkInfo.msg"' in cmake and "DEPENDENCIES std_msgs" in cmake
fields = get_types_from_msg(open("ros2/bass_msgs/msg/ChunkInfo.msg").read(), "bass_msgs/msg/ChunkInfo")
consts, names = fields["bass_msgs/msg/ChunkInfo"]
print(f"{p.name} {p.version}, format {p.package_format}: valid; ChunkInfo: {len(consts)} constants, "
      f"{len(names)} fields ({', '.join(n for n, _ in names)})")
PY
); then ok "bass_msgs: $P"; else bad "bass_msgs package: $P"; fi

echo "== 1. peer to peer: serve --ros2 beside a mirror"
start_source; wait_port "$DIR_A" src
start_serve --ros2; start_mirror; wait_replica
wait_for 10 grep -q 'Zenoh session open' "$WORK/serve.log" || bad "serve never opened its session"
Z=$(zid_of "$WORK/serve.log")
reader $((RATE * 4)) 20 >"$WORK/r1.json" & R=$!
if J=$(sub "$EP" peer "$Z" 0 bass_bridge_src /bass/src/audio); then
  ok "ROS 2 topics read by an independent subscriber: $J"
else bad "ROS 2 subscriber (peer): $J"; fi
wait $R || true; check_exact "$(cat "$WORK/r1.json")" "the replica beside --ros2"
grep -q 'ROS 2 node (rmw_zenoh layout) node=bass_bridge_src domain=0' "$WORK/serve.log" \
  && ok "serve logs its ROS 2 node" || bad "no ROS 2 node line in serve's log"

echo "== 2. through a Zenoh router, serve in client mode, domain 7, the user's topic and node"
kill "$SERVE" 2>/dev/null || true; wait "$SERVE" 2>/dev/null || true
REP="tcp/[$ADDR_A]:7448"
# The suite's router (no zenohd here): a serve of a broker that does not exist only routes.
"${IN_A[@]}" "$BIN/bass-bridge" serve --mode router --name none --namespace router --listen "$REP" \
  --no-scouting "${INSECURE[@]}" >>"$WORK/router.log" 2>&1 &
PIDS+=($!)
# A Zenoh client does not start without its router.
wait_for 10 grep -q 'Zenoh session open' "$WORK/router.log" || bad "the router never opened its session"
"${IN_A[@]}" env ROS_DOMAIN_ID=7 "$BIN/bass-bridge" serve --name src --mode client --connect "$REP" \
  --no-scouting "${INSECURE[@]}" --ros2 --ros2-topic /robot/mic/audio --ros2-node mic \
  >>"$WORK/serve-client.log" 2>&1 &
SC=$!; PIDS+=($SC)
wait_for 10 grep -q 'Zenoh session open' "$WORK/serve-client.log" || bad "client serve never opened its session"
Z=$(zid_of "$WORK/serve-client.log")
if J=$(sub "$REP" peer "$Z" 7 mic /robot/mic/audio); then
  ok "ROS 2 topics through a router (client serve, domain 7, /robot/mic/audio): $J"
else bad "ROS 2 subscriber through the router: $J"; fi

echo "== 3. Humble layout; a bad topic refused; SIGTERM takes the node off the graph"
kill "$SC" 2>/dev/null || true; wait "$SC" 2>/dev/null || true
"${IN_A[@]}" "$BIN/bass-bridge" serve --name src --mode client --connect "$REP" --no-scouting \
  "${INSECURE[@]}" --ros2 --ros2-distro humble >>"$WORK/serve-humble.log" 2>&1 &
SH=$!; PIDS+=($SH)
HK="0/bass/src/audio/audio_common_msgs::msg::dds_::AudioDataStamped_/TypeHashNotSupported"
# A plain Zenoh subscriber on the key Humble's rmw_zenoh uses: messages arrive.
count_humble() {
  inB timeout 30 python3 - "$REP" "$HK" <<'PY'
import json, sys, time, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"peer"'); c.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
c.insert_json5("scouting/multicast/enabled", "false"); c.insert_json5("scouting/gossip/enabled", "false")
s = zenoh.open(c); got = []
sub = s.declare_subscriber(sys.argv[2], lambda x: got.append(len(x.attachment.to_bytes()) if x.attachment else 0))
t = time.time() + 15
while time.time() < t and len(got) < 50: time.sleep(0.05)
tok = [str(r.ok.key_expr) for r in s.liveliness().get("@ros2_lv/0/**", timeout=2) if r.ok]
print(len(got), set(got), sum("/TypeHashNotSupported/" in k for k in tok))
PY
}
OUT=$(count_humble) || true
read -r N ATT TOK <<<"$OUT"
(( ${N:-0} >= 50 )) && [[ $ATT == "{33}" && $TOK == 3 ]] \
  && ok "Humble layout: $N messages on $HK, 33-byte attachments, 3 publisher tokens with TypeHashNotSupported" \
  || bad "Humble layout: $OUT"
RC=0; inA timeout 10 "$BIN/bass-bridge" serve --name src --ros2 --ros2-topic bass/no_slash >/dev/null 2>"$WORK/bad.err" || RC=$?
[[ $RC == 2 ]] && grep -q 'not a ROS 2 topic name' "$WORK/bad.err" \
  && ok "a bad --ros2-topic is refused (exit 2): $(cat "$WORK/bad.err")" || bad "bad topic: exit $RC $(cat "$WORK/bad.err")"
MS=$(term_ms "$SH")
tokens_left() {
  inB timeout 20 python3 - "$REP" <<'PY'
import json, sys, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"peer"'); c.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
c.insert_json5("scouting/multicast/enabled", "false"); c.insert_json5("scouting/gossip/enabled", "false")
s = zenoh.open(c)
import time; time.sleep(1)
print(len([r for r in s.liveliness().get("@ros2_lv/**", timeout=2) if r.ok]))
PY
}
LEFT=$(tokens_left) || true
[[ $MS != never ]] && (( MS < 1000 )) && [[ $LEFT == 0 ]] \
  && ok "SIGTERM: serve --ros2 ended in $MS ms, no ROS 2 token left on the router" \
  || bad "SIGTERM: $MS ms, $LEFT tokens left"
rig_done
