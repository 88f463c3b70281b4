#!/usr/bin/env bash
# Network case "outage": the robot's address going away and coming back; serve restarted
# while the link is down; SIGTERM ending serve and mirror within a second while their link
# is dead (a Zenoh call may be blocked then). The plain link outages are in basic (3 s) and
# outage-long-* (15 s, 60 s).
source "$(dirname "$0")/../lib.sh"
rig_up
start_source; start_serve; start_mirror; wait_replica

echo "== robot's address removed for 6 s, then back"
reader $((RATE * 16)) 50 >"$WORK/r1.json" & R=$!
sleep 2; ip -n "$NS_A" addr del $ADDR_A/64 dev vA; sleep 6; ip -n "$NS_A" addr add $ADDR_A/64 dev vA nodad
wait $R || true; J=$(cat "$WORK/r1.json")
check_exact "$J" "address gone"
(( $(field "$J" gap) + $(field "$J" lost) > 0 && $(field "$J" delivered) > RATE * 4 )) \
  && ok "address gone: the outage marked, data again afterwards ($J)" || bad "address gone: $J"

echo "== serve restarted while the link is down (same source epoch: the replica port is kept)"
reader $((RATE * 16)) 50 >"$WORK/r2.json" & R=$!
sleep 2; ip -n "$NS_A" link set vA down; sleep 1
MS=$(term_ms "$SERVE")
[[ $MS != never ]] && (( MS <= 1000 )) && ok "SIGTERM ended serve in $MS ms with its link dead" || bad "serve took $MS ms to end after SIGTERM"
start_serve; sleep 4; ip -n "$NS_A" link set vA up
wait $R || true; J=$(cat "$WORK/r2.json")
check_exact "$J" "serve restarted during the outage"
[[ $(field "$J" restarts) == 0 ]] && (( $(field "$J" delivered) > RATE * 4 )) \
  && ok "serve restarted during the outage: same replica, data again ($J)" || bad "serve restart during outage: $J"

echo "== SIGTERM ends the mirror within a second while its link is dead"
ip -n "$NS_A" link set vA down; sleep 4
MS=$(term_ms "$MIRROR")
[[ $MS != never ]] && (( MS <= 1000 )) && ok "SIGTERM ended the mirror in $MS ms with its link dead" || bad "the mirror took $MS ms to end after SIGTERM"
ip -n "$NS_A" link set vA up
rig_done
