#!/usr/bin/env bash
# Network case "names": a mirror takes its replica's name as bassd does (the instance lock):
# a name held by a local broker or another mirror is refused (exit 2) naming the holder and
# the holder keeps working; SIGTERM removes the mirror's socket, port and lock; a socket left
# by a killed mirror is replaced; 300 idle connections to its control socket do not make 300
# threads.
source "$(dirname "$0")/../lib.sh"
rig_up
BB=$BIN/bass-bridge
mirror_args=(mirror --source src --connect "$EP" --no-scouting --insecure --timeout 1)

echo "== a mirror named like a live local broker is refused; the broker stays controllable"
"${IN_B[@]}" "$BIN/bassd" --name src2 --rt-priority 0 --acquire sim:pattern --rate $RATE --frames $NFPC \
  --chunks $NCOP --channels 2 >>"$WORK/bassd-b.log" 2>&1 &
LOCAL=$!; PIDS+=($LOCAL)
wait_for 10 test -S "$DIR_B/bass-src2.sock" || bad "local bassd src2 never listened"
RC=0; OUT=$(inB timeout 10 "$BB" "${mirror_args[@]}" --name src2 2>&1) || RC=$?
[[ $RC == 2 ]] && grep -q "pid $LOCAL (bassd)" <<<"$OUT" && ok "refused, exit 2, naming the holder: $(tail -1 <<<"$OUT" | cut -c1-220)" \
  || bad "mirror --name src2 (exit $RC): $OUT"
OUT=$(inB timeout 10 "$BIN/bass" --name src2 status 2>&1) && grep -q capturing <<<"$OUT" \
  && ok "bass --name src2 status still reaches the local bassd" || bad "local bassd lost its socket: $OUT"

echo "== a second mirror with the name of a first is refused; the first goes on"
start_source; start_serve; start_mirror
wait_replica
RC=0; OUT=$(inB timeout 10 "$BB" "${mirror_args[@]}" --name rep 2>&1) || RC=$?
[[ $RC == 2 ]] && grep -q "pid $MIRROR (bass-bridge)" <<<"$OUT" && ok "second mirror refused naming the first: $(tail -1 <<<"$OUT" | cut -c1-220)" \
  || bad "second mirror --name rep (exit $RC): $OUT"
J=$(reader $((RATE * 2)) 20) || true
check_exact "$J" "first mirror after the refused second"
OUT=$(inB timeout 20 "$BIN/bass" --name rep status 2>&1) || true
grep -q "allow-control" <<<"$OUT" && ok "the first mirror's control socket still answers" || bad "first mirror's socket: $OUT"

echo "== 300 idle connections to the mirror's control socket"
T0=$(awk '/^Threads:/ {print $2}' /proc/$MIRROR/status)
inB timeout 60 python3 - "$DIR_B/bass-rep.sock" "/proc/$MIRROR/status" >"$WORK/flood.json" <<'PY' || true
import json, socket, sys, time
conns = []
for _ in range(300):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    s.connect(sys.argv[1])
    conns.append(s)
time.sleep(2)
threads = int([l for l in open(sys.argv[2]) if l.startswith("Threads:")][0].split()[1])
# The refused ones were told why (and closed).
refused = 0
for s in conns:
    s.settimeout(0.05)
    try:
        if b"too many control connections" in s.recv(65536):
            refused += 1
    except OSError:
        pass
print(json.dumps({"threads": threads, "refused": refused}))
PY
F=$(cat "$WORK/flood.json")
TH=$(field "$F" threads); RF=$(field "$F" refused)
(( TH <= T0 + 20 )) && ok "threads $T0 before, $TH with 300 idle connections" || bad "threads $T0 before, $TH with 300 connections"
(( RF >= 250 )) && ok "$RF connections refused with a reason" || bad "only $RF connections refused with a reason"
sleep 0.5
OUT=$(inB timeout 20 "$BIN/bass" --name rep status 2>&1) || true
grep -q "allow-control" <<<"$OUT" && ok "after the flood the socket answers again" || bad "after the flood: $OUT"

echo "== SIGTERM removes the socket, the port and the lock"
kill -TERM "$MIRROR"; RC=0; wait "$MIRROR" || RC=$?
LEFT=$(cd "$DIR_B" && ls bass-rep.* 2>/dev/null || true)
[[ $RC == 0 && -z $LEFT ]] && ok "mirror exited 0 and left nothing of bass-rep" || bad "exit $RC, left: $LEFT"

echo "== a socket left by a killed mirror is replaced by the next one"
start_mirror; wait_replica
kill -KILL "$MIRROR"; wait "$MIRROR" 2>/dev/null || true
[[ -S $DIR_B/bass-rep.sock ]] || bad "SIGKILL left no socket (nothing to test)"
start_mirror
wait_for 10 grep -q 'removed the stale control socket' "$WORK/mirror.log" \
  && ok "the next mirror removed the dead one's socket" || bad "stale socket: $(tail -3 "$WORK/mirror.log")"
J=$(reader $((RATE * 2)) 20) || true
check_exact "$J" "mirror after a SIGKILLed one"
echo "== a replica it cannot make, and a status file it cannot write: an error state, not an exit"
"${IN_B[@]}" "$BB" "${mirror_args[@]}" --name small --max-port-bytes 65536 --status-file "$DIR_B/small.json" \
  >>"$WORK/mirror-small.log" 2>&1 &
SMALL=$!; PIDS+=($SMALL)
"${IN_B[@]}" "$BB" "${mirror_args[@]}" --name nostat --status-file "$DIR_B/no/such/dir/status.json" \
  >>"$WORK/mirror-nostat.log" 2>&1 &
NOSTAT=$!; PIDS+=($NOSTAT)
wait_port "$DIR_B" nostat || bad "mirror nostat never made its replica"
sleep 2.5
ERR=$(status error "$DIR_B/small.json" 2>/dev/null || echo none)
kill -0 $SMALL 2>/dev/null && [[ ! -e $DIR_B/bass-small.port ]] && grep -q -- "--max-port-bytes" <<<"$ERR" \
  && ok "a replica above --max-port-bytes: mirror alive, no port, status error: $ERR" || bad "small: alive? error: $ERR; $(tail -3 "$WORK/mirror-small.log")"
kill -0 $NOSTAT 2>/dev/null && grep -q "status file" "$WORK/mirror-nostat.log" \
  && ok "an unwritable status file is logged, the mirror goes on: $(grep -m1 'status file' "$WORK/mirror-nostat.log" | cut -c1-200)" \
  || bad "nostat: $(tail -3 "$WORK/mirror-nostat.log")"
(( $(grep -c "status file" "$WORK/mirror-nostat.log") <= 2 )) && ok "its failures are logged at most once per 5 s" || bad "status-file failures flood the log"
echo "== mirror --group: the replica is the group's to read (issue 33)"
"${IN_B[@]}" "$BB" "${mirror_args[@]}" --name grp --group nogroup >>"$WORK/mirror-grp.log" 2>&1 &
GRP=$!; PIDS+=($GRP)
wait_port "$DIR_B" grp || bad "mirror grp never made its replica"
M=$(stat -c '%G %a' "$DIR_B/bass-grp.port" 2>&1)
# A process of the group only (uid nobody, gid nogroup, no other group) reads the port file.
chmod o+x "$WORK" "$DIR_B"
if [[ $M == "nogroup 640" ]] && setpriv --reuid 65534 --regid "$(getent group nogroup | cut -d: -f3)" --clear-groups \
     head -c 8 "$DIR_B/bass-grp.port" >/dev/null; then
  ok "mirror --group nogroup: replica port $M, read by a member of the group only"
else bad "mirror --group: replica port $M; $(tail -3 "$WORK/mirror-grp.log")"; fi
"${IN_B[@]}" "$BB" "${mirror_args[@]}" --name grp2 --group no-such-group-here >"$WORK/mirror-grp2.log" 2>&1 && rc=0 || rc=$?
(( rc == 2 )) && grep -q 'no group "no-such-group-here"' "$WORK/mirror-grp2.log" \
  && ok "an unknown --group is refused by name (exit 2)" || bad "unknown group: exit $rc: $(tail -2 "$WORK/mirror-grp2.log")"
rig_done
