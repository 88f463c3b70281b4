# Body of the long link-outage cases (cases/outage-long-*.sh set OUTAGE, in seconds): the
# robot's link goes down for OUTAGE seconds (longer than Zenoh's lease, so the transport
# closes on both sides) and comes back; nothing is restarted. Asserted: every sample the
# reader got is right, delivered + lost + gap = requested, the outage is GAP or loss at its
# frame indices, and data flows again. Printed: how long after the link returned the
# replica carried data again (the goal is <= 2 s; `make bench` reports it too; a time is
# not asserted: the machines are shared).
CASE_LIMIT=$((OUTAGE + 120))
source "$(dirname "$0")/../lib.sh"
rig_up
start_bassd; start_serve; start_mirror; wait_replica
AFTER=12
reader $((RATE * (2 + OUTAGE + AFTER))) $((OUTAGE + AFTER + 40)) >"$WORK/r.json" & R=$!
sleep 2; ip -n "$NS_A" link set vA down
echo "  link down for $OUTAGE s"
sleep "$OUTAGE"
# The link comes back inside scripts/bench-net-recovery.py (the bench's own measurement), which
# then polls both ports: seconds until the replica moved again and until it held the
# source's newest frame at link-up.
REC=$(inB env BASS_LIB="$BIN/libbassclient.so" timeout 40 python3 scripts/bench-net-recovery.py \
  "$DIR_A" src "$DIR_B" rep 30 -- ip -n "$NS_A" link set vA up) || REC='{"moved_s": null, "live_s": null}'
MOVED=$(field "$REC" moved_s); LIVE=$(field "$REC" live_s)
[[ $MOVED == None ]] || MOVED=$(printf %.2f "$MOVED"); [[ $LIVE == None ]] || LIVE=$(printf %.2f "$LIVE")
wait $R || true; J=$(cat "$WORK/r.json")
check_exact "$J" "$OUTAGE s outage"
(( $(field "$J" gap) + $(field "$J" lost) >= RATE * (OUTAGE - 1) )) \
  && ok "$OUTAGE s outage: the outage is GAP frames or loss at its indices (gap $(field "$J" gap), lost $(field "$J" lost))" \
  || bad "$OUTAGE s outage left too little gap: $J"
if [[ $LIVE != None ]] && (( $(field "$J" delivered) > RATE * (AFTER - 6) )) && kill -0 "$SERVE" && kill -0 "$MIRROR"; then
  ok "$OUTAGE s outage: recovered without a restart: replica moving ${MOVED} s and live ${LIVE} s after the link returned (goal 2 s)"
else bad "$OUTAGE s outage: no recovery ($REC; $J)"; fi
sleep 1.5
(( $(status outages) >= 1 )) && ok "$OUTAGE s outage: the mirror counted it ($(status outages) outage(s))" || bad "outage not counted"
rig_done
