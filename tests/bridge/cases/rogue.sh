#!/usr/bin/env bash
# Network case "rogue": a hostile peer on an open bridge (--insecure: defence in depth). A real
# Zenoh session (tests/bridge/rogue_peer.py, PyPI eclipse-zenoh) connects to the mirror's
# endpoint while the real serve goes on and sends what used to crash, freeze, churn or
# poison the replica (issue 20): a 1 TiB geometry, a chunk at frame ~2^62, 10 chunks of
# 0x7fffffff from another instance, forged states, 50 new epochs, garbage, clock answers of
# 2.7e17, a control answer full of terminal escapes. The replica must carry the real stream
# only, sample for sample, with exact accounting; the refusals counted; no raw escape
# reaches a terminal or a log; the clock estimate stays sane.
source "$(dirname "$0")/../lib.sh"
rig_up
ROGUE_EP="tcp/[$ADDR_B]:7450"

start_source; start_serve; start_mirror --listen "$ROGUE_EP"
wait_replica
# The clock estimate needs a few rounds from the real source first (a sane estimate exists).
wait_for 10 bash -c "python3 -c \"import json,sys; sys.exit(json.load(open('$DIR_B/status.json'))['clock_offset_ns'] is None)\"" \
  || bad "no clock estimate before the rogue came"

echo "== the rogue peer, while a reader reads the replica"
reader $((RATE * 12)) 30 >"$WORK/r.json" & R=$!
sleep 1
inB timeout 60 python3 tests/bridge/rogue_peer.py "$ROGUE_EP,$EP" bass src 8 >"$WORK/rogue.json" 2>"$WORK/rogue.log" & RP=$!
sleep 4
# serve has no --allow-control: only the rogue answers a forwarded request (ListDevices; a
# Status is the mirror's own answer, which takes only a Status as the source's live one).
OUT=$(inB timeout 20 "$BIN/bass" --name rep devices 2>&1) || true
printf '%s' "$OUT" >"$WORK/bass-devices.txt"
if grep -q $'\x1b' "$WORK/bass-devices.txt"; then bad "bass devices printed a raw ESC: $(cat -v "$WORK/bass-devices.txt")"
elif grep -qF '\x1b]0;owned by rogue' "$WORK/bass-devices.txt"; then ok "bass devices shows the rogue's control answer escaped: $(head -c 160 "$WORK/bass-devices.txt")"
else bad "bass devices did not show the rogue's answer: $(cat -v "$WORK/bass-devices.txt" | head -c 300)"; fi
OUT=$(inB timeout 20 "$BIN/bass" --name rep status 2>&1) || true
printf '%s' "$OUT" >"$WORK/bass-status.txt"
if grep -q $'\x1b' "$WORK/bass-status.txt"; then bad "bass status printed a raw ESC: $(cat -v "$WORK/bass-status.txt")"
elif grep -q "source live not asked" "$WORK/bass-status.txt"; then ok "bass status: the mirror's own answer, the rogue's error not taken as the source's Status"
else bad "bass status of the replica under attack: $(cat -v "$WORK/bass-status.txt" | head -c 300)"; fi
RC=0; wait $RP || RC=$?
[[ $RC == 0 ]] && ok "rogue peer connected and sent everything: $(cat "$WORK/rogue.json")" || bad "rogue peer exit $RC: $(cat "$WORK/rogue.log")"
wait $R || true; J=$(cat "$WORK/r.json")

echo "== the replica carries the real stream only"
kill -0 "$MIRROR" 2>/dev/null && ok "mirror alive" || bad "mirror died: $(tail -5 "$WORK/mirror.log")"
check_exact "$J" "replica under attack"
[[ $(field "$J" restarts) == 0 && $(field "$J" gap) == 0 && $(field "$J" lost) == 0 ]] \
  && ok "no restart, no gap, no loss: no forged chunk was applied" || bad "the rogue moved the replica: $J"
sleep 1.5
for c in invalid_messages refused_far_frames refused_other_source refused_states clock_replies_refused; do
  v=$(status $c); (( v > 0 )) && ok "$c = $v" || bad "$c = $v (want > 0)"
done
(( $(status invalid_messages) >= 4 )) && ok "the 1 TiB geometry and the garbage counted invalid" || bad "invalid_messages $(status invalid_messages)"
(( $(status refused_other_source) >= 60 )) && ok "10 forged chunks and 50 forged epochs of other instances refused" \
  || bad "refused_other_source $(status refused_other_source) < 60"
[[ $(status replica_recreations) == 1 ]] && ok "one replica port made, none for the forged epochs" || bad "replica_recreations $(status replica_recreations)"
OFF=$(status clock_offset_ns)
[[ $OFF != None ]] && (( ${OFF#-} < 1000000000 )) && ok "clock offset sane beside 2.7e17 answers: $OFF ns" || bad "clock offset $OFF"
grep -q "two sources named \"src\"" "$WORK/mirror.log" && ok "the other instance is reported: $(grep -o 'two sources named[^;]*' "$WORK/mirror.log" | head -1)" \
  || bad "no two-sources report in the log"
grep -q $'\x1b' "$WORK/mirror.log" && bad "raw ESC in the mirror's log" || ok "no raw ESC in the mirror's log"
# The replica's own header text (bass blocks prints it) is clean too: its two text fields,
# message (offset 256, 256 bytes) and device (512, 128 bytes; docs/port-format.md). The
# numeric fields around them may hold the byte 0x1b by chance (a timestamp's low byte).
INFO=$(inB timeout 10 python3 - "$DIR_B/bass-rep.port" <<'PY'
import sys
b = open(sys.argv[1], "rb").read(4096)
print("esc" if b"\x1b" in b[256:640] else "clean")
PY
)
[[ $INFO == clean ]] && ok "no raw ESC in the replica port's header" || bad "raw ESC in the replica's header"
rig_done
