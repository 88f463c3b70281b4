#!/usr/bin/env bash
# Network case "ros2_acl" (docs/ros2.md, "Security"): an authenticated workstation cannot make a
# ROS consumer decode forged audio. Every peer is a real Zenoh session (PyPI eclipse-zenoh;
# tests/bridge/ros2_peer.py: rosbags makes and reads the CDR, rmw_zenoh's keys and attachment):
#  0. serve --ros2 without authentication on a network is refused (exit 2), as plain serve;
#  1. the ROS graph's router (the suite's: a bass-bridge serve of no broker in router mode) admits
#     robot, ws1, ws2 with bass credentials; serve --ros2 in client mode as robot, the consumer as
#     ws1 (B), the forger as ws2 (C) putting 50 well-formed AudioDataStamped on the audio key.
#     No ACL on the router: the consumer decodes them (the check can see a forgery); with
#     docs/zenoh/acl-ros2-router.json5: none, and the real audio arrives contiguous, the
#     latched AudioInfo too, and ws2 is still an ordinary ROS node (its own topic arrives);
#  2. serve --ros2 as the router itself: its own guard (no --zenoh-config) covers its ROS keys;
#     BASS_BRIDGE_NO_ACL=1 (tests only) shows what it stops.
source "$(dirname "$0")/../lib.sh"
rig_up 3
INSECURE=()
BB=$BIN/bass-bridge; BF=$BIN/bass-bridge-faults
P=tests/bridge/ros2_peer.py
SECS=4

echo "== 0. serve --ros2 without authentication on a network: refused (exit 2)"
RC=0; OUT=$(inA timeout 10 $BB serve --name src --listen "$EP" --no-scouting --ros2 2>&1) || RC=$?
[[ $RC == 2 ]] && grep -q "refusing to run without authentication on" <<<"$OUT" \
  && ok "serve --ros2 refused without authentication: $(grep -o 'refusing to run without authentication on [^:]*:[^ ]*' <<<"$OUT" | head -1)" \
  || bad "serve --ros2 without authentication (exit $RC): $OUT"

C=$WORK/cred; mkdir -p "$C"
for id in router robot ws1 ws2; do $BB credentials "$C/$id.cred" --user $id 2>/dev/null; done
for id in robot ws1 ws2; do
  $BB credentials "$C/$id.cred" --trust "$C/router.pub" 2>/dev/null
  $BB credentials "$C/router.cred" --trust "$C/$id.pub" 2>/dev/null
done
for id in ws1 ws2; do
  $BB credentials "$C/$id.cred" --trust "$C/robot.pub" 2>/dev/null
  $BB credentials "$C/robot.cred" --trust "$C/$id.pub" 2>/dev/null
done
start_source; wait_port "$DIR_A" src

# judge LABEL ACL(on|off) CONSUMER_JSON FORGER_JSON
judge() {
  local what=$1 acl=$2 j=$3 f=$4
  [[ $(field "$f" put) == 50 ]] || { bad "$what: forger: $f"; return; }
  local good bad_ contig info
  good=$(field "$j" audio_good); bad_=$(field "$j" audio_bad); contig=$(field "$j" contiguous); info=$(field "$j" audio_info)
  if [[ $acl == off ]]; then
    (( bad_ > 0 )) && ok "$what, no ACL: the consumer decoded $bad_ of ws2's 50 forged messages (the check sees a forgery)" \
      || bad "$what, no ACL: no forged message arrived: $j"
  else
    [[ $bad_ == 0 && $contig == True ]] && (( good >= SECS * RATE / NFPC - 20 )) && grep -q "'rate': $RATE" <<<"$info" \
      && [[ $(field "$j" other) == 50 ]] \
      && ok "$what, ACL: audio_bad 0, $good real messages, contiguous frames, latched AudioInfo $info; ws2's 50 messages on its own /ws2/chatter arrived" \
      || bad "$what, ACL: $j"
  fi
}
# round LABEL ACL ENDPOINT_B ENDPOINT_C TO: consumer ws1 in B, forger ws2 in C, both logged in to TO
round() {
  local what=$1 acl=$2 epb=$3 epc=$4 to=$5 pw1 pw2 f cons
  pw1=$($BF --print-pair-password "$C/ws1.cred" ws1 "$to"); pw2=$($BF --print-pair-password "$C/ws2.cred" ws2 "$to")
  rm -f "$WORK/ready"
  ( inB timeout 60 python3 $P consume "$epb" ws1 "$pw1" src $SECS "$WORK/ready" >"$WORK/consume.json" || true ) &
  cons=$!
  wait_for 20 test -f "$WORK/ready" || bad "$what: the consumer never subscribed"
  f=$(inC timeout 40 python3 $P forge "$epc" ws2 "$pw2" src 50) || true
  wait $cons
  judge "$what" "$acl" "$(cat "$WORK/consume.json")" "$f"
}

echo "== 1. through the ROS graph's router: no ACL, then docs/zenoh/acl-ros2-router.json5"
port=7470
for acl in off on; do
  port=$((port + 1)); RA="tcp/[$ADDR_A]:$port"; RC3="tcp/[fd00:ba57::1]:$port"
  envs=(); cfg=()
  if [[ $acl == off ]]; then envs=(BASS_BRIDGE_NO_ACL=1); else cfg=(--zenoh-config docs/zenoh/acl-ros2-router.json5); fi
  "${IN_A[@]}" "${envs[@]}" $BB serve --mode router --name none --namespace router --listen "$RA" --listen "$RC3" \
    --no-scouting --credentials "$C/router.cred" "${cfg[@]}" >>"$WORK/router-$acl.log" 2>&1 &
  RT=$!; PIDS+=($RT)
  wait_for 10 grep -q 'Zenoh session open' "$WORK/router-$acl.log" || bad "router ($acl) never opened its session"
  "${IN_A[@]}" $BB serve --name src --mode client --connect "$RA" --no-scouting --credentials "$C/robot.cred" \
    --peer router --ros2 >>"$WORK/serve-$acl.log" 2>&1 &
  SV=$!; PIDS+=($SV)
  wait_for 10 grep -q 'ROS 2 node' "$WORK/serve-$acl.log" || bad "serve --ros2 ($acl) never declared its node"
  round "router" $acl "$RA" "$RC3" router
  kill $SV $RT 2>/dev/null || true; wait $SV $RT 2>/dev/null || true
done
grep -q 'access control: the one of --zenoh-config' "$WORK/router-on.log" \
  && ok "the router runs the shipped ACL (bass adds none)" || bad "router-on.log: no access control line"

echo "== 2. serve --ros2 as the router: its own guard covers its ROS keys"
for acl in off on; do
  port=$((port + 1)); RA="tcp/[$ADDR_A]:$port"; RC3="tcp/[fd00:ba57::1]:$port"
  envs=(); [[ $acl == off ]] && envs=(BASS_BRIDGE_NO_ACL=1)
  "${IN_A[@]}" "${envs[@]}" $BB serve --name src --mode router --listen "$RA" --listen "$RC3" --no-scouting \
    --credentials "$C/robot.cred" --ros2 >>"$WORK/serve-router-$acl.log" 2>&1 &
  SV=$!; PIDS+=($SV)
  wait_for 10 grep -q 'ROS 2 node' "$WORK/serve-router-$acl.log" || bad "serve --ros2 --mode router ($acl) never declared its node"
  round "serve as router" $acl "$RA" "$RC3" robot
  kill $SV 2>/dev/null || true; wait $SV 2>/dev/null || true
done
rig_done
