#!/usr/bin/env bash
# Network case "security" (docs/network.md, "Security", the threat table): strangers get
# nothing; a trusted colleague cannot put one frame into another machine's replica under any
# identity it holds; remote control is authorized per identity and logged; no secret in any
# output. Robot = A, workstation ws1 = B, colleague ws2 = C (and a process of ws2's in B where
# it must reach ws1 directly). Every hostile peer is a real Zenoh session (PyPI eclipse-zenoh).
source "$(dirname "$0")/../lib.sh"
rig_up 3
INSECURE=()
BB=$BIN/bass-bridge; BF=$BIN/bass-bridge-faults
EP_C="tcp/[fd00:ba57::1]:7447"   # the robot as ws2 reaches it
WS1_EP="tcp/[$ADDR_B]:7449"      # ws1's mirror listens here too
S=tests/bridge/stranger.py

echo "== no authentication, not loopback: refused (exit 2) unless --insecure"
for args in "serve --name src --listen $EP --no-scouting" "mirror --source src --connect $EP --no-scouting" "serve --name src"; do
  RC=0; OUT=$(inA timeout 10 $BB $args 2>&1) || RC=$?
  if [[ $RC == 2 ]] && grep -q "refusing to run without authentication on" <<<"$OUT" && grep -q -- "--credentials FILE" <<<"$OUT"; then
    ok "'$args' refused: $(grep -o 'refusing to run without authentication on [^:]*:[^ ]*' <<<"$OUT" | head -1)"
  else bad "'$args' not refused (exit $RC): $OUT"; fi
done
RC=0; inA timeout 2 $BB serve --name lo --listen "tcp/[::1]:7460" --no-scouting >"$WORK/lo.log" 2>&1 || RC=$?
[[ $RC == 124 ]] && ok "loopback only, no scouting: runs without credentials" || bad "loopback serve exited $RC: $(cat "$WORK/lo.log")"
RC=0; inA timeout 2 $BB serve --name lo --listen "$EP" --no-scouting --insecure >"$WORK/open.log" 2>&1 || RC=$?
[[ $RC == 124 ]] && grep -q "INSECURE: no authentication on tcp/\[$ADDR_A\]:7447" "$WORK/open.log" \
  && ok "--insecure runs open and says so in the log" || bad "--insecure (exit $RC): $(cat "$WORK/open.log")"

echo "== names with wildcard or key-expression characters are refused by name"
for args in "serve --name *" "serve --name a/b" "mirror --source * --insecure" "mirror --source src --name x\$y --insecure" "serve --namespace bass/** --insecure"; do
  read -ra argv <<<"$args"   # word-split only: a '*' stays a '*'
  RC=0; OUT=$(inA timeout 10 $BB "${argv[@]}" --listen "tcp/[::1]:7461" --no-scouting 2>&1) || RC=$?
  [[ $RC == 2 ]] && grep -q "no wildcard or key-expression characters" <<<"$OUT" && ok "'$args' refused: ${OUT:0:90}" \
    || bad "'$args' (exit $RC): $OUT"
done

echo "== credentials as the README makes them: private files, public cards exchanged"
C=$WORK/cred; mkdir -p "$C"
$BB credentials "$C/robot.cred" --user robot 2>/dev/null
$BB credentials "$C/ws1.cred" --user ws1 --trust "$C/robot.pub" 2>/dev/null
$BB credentials "$C/ws2.cred" --user ws2 --trust "$C/robot.pub" 2>/dev/null
$BB credentials "$C/robot.cred" --trust "$C/ws1.pub" --trust "$C/ws2.pub" 2>/dev/null
[[ $(stat -c %a "$C/robot.cred") == 600 && $(grep -c '^trust ' "$C/robot.cred") == 2 ]] \
  && ok "robot.cred is 0600 and trusts ws1 and ws2" || bad "credentials files: $(ls -l "$C")"
SEEDS=$(grep -h '^seed ' "$C"/*.cred | cut -d' ' -f2)
if cat "$C"/*.pub | grep -qF "$SEEDS"; then bad "a public card holds a seed"; else ok "the public cards hold no secret"; fi
RC=0; OUT=$(timeout 5 $BB credentials "$C/ws1.cred" --trust "$C/robot.cred" 2>&1) || RC=$?
[[ $RC == 2 ]] && grep -q "is a private credentials file" <<<"$OUT" && ok "trusting a private file is refused: never copy it" || bad "trust of robot.cred (exit $RC): $OUT"
mkfifo "$C/fifo.pub"
RC=0; OUT=$(timeout 5 $BB credentials "$C/ws1.cred" --trust "$C/fifo.pub" 2>&1) || RC=$?
[[ $RC == 2 ]] && grep -q "not a regular file" <<<"$OUT" && ok "a FIFO is refused by name, without hanging" || bad "trust of a FIFO (exit $RC): $OUT"
rm -f "$C/fifo.pub"
printf '# bass-bridge credentials: first line = this machine; all lines = accepted\nrobot:0123456789abcdef0123456789abcdef\n' >"$C/old.cred"; chmod 600 "$C/old.cred"
RC=0; OUT=$(inA timeout 10 $BB serve --name src --listen "$EP" --no-scouting --credentials "$C/old.cred" 2>&1) || RC=$?
[[ $RC == 2 ]] && grep -q "old shared-password credentials file" <<<"$OUT" && ! grep -q 0123456789abcdef <<<"$OUT" \
  && ok "a version-1 file is refused, saying why, without its content" || bad "old file (exit $RC): $OUT"

start_source
start_serve --listen "$EP_C" --credentials "$C/robot.cred" --allow-control ws1
"${IN_B[@]}" $BB mirror --source src --name rep --connect "$EP" --listen "$WS1_EP" --no-scouting --timeout 1 \
  --credentials "$C/ws1.cred" --status-file "$DIR_B/status.json" >>"$WORK/mirror.log" 2>&1 &
MIRROR=$!; PIDS+=($MIRROR)
wait_replica
J=$(reader $((RATE * 2)) 20) || true
check_exact "$J" "authenticated bridge"
sleep 1.2
[[ $(status source_identity) == robot && $(status insecure) == False ]] && ok "status: source identity robot, insecure false" \
  || bad "status: $(cat "$DIR_B/status.json")"

echo "== strangers: every line of every file, as Zenoh would read it, gets no session"
L=$(inB timeout 60 python3 $S lines "$EP" "$C"/robot.cred "$C"/ws1.cred "$C"/ws2.cred "$C"/*.pub) || true
[[ $(field "$L" admitted) == "[]" ]] && (( $(field "$L" tried) >= 12 )) \
  && ok "serve: $(field "$L" tried) identities tried (the version-1 comment line included), none admitted" || bad "serve admitted: $L"
L=$(inB timeout 60 python3 $S lines "$WS1_EP" "$C"/robot.cred "$C"/ws1.cred "$C"/ws2.cred "$C"/*.pub) || true
[[ $(field "$L" admitted) == "[]" ]] && ok "ws1's mirror: $(field "$L" tried) identities tried, none admitted" || bad "mirror admitted: $L"
# A peer without credentials, and one whose keys the robot does not know (its own "robot" card
# trusted: a wrong derived password), get no replica; the latter says why.
"${IN_B[@]}" $BB mirror --source src --name open --connect "$EP" --no-scouting --insecure >"$WORK/open-mirror.log" 2>&1 &
OPEN=$!; PIDS+=($OPEN)
mkdir -p "$C/fake"
$BB credentials "$C/fake/robot.cred" --user robot 2>/dev/null
$BB credentials "$C/fake/ws1.cred" --user ws1 --trust "$C/fake/robot.pub" 2>/dev/null
"${IN_B[@]}" $BB mirror --source src --name wrong --connect "$EP" --no-scouting --credentials "$C/fake/ws1.cred" \
  >"$WORK/wrong-mirror.log" 2>&1 &
WRONG=$!; PIDS+=($WRONG)
sleep 5
[[ ! -e $DIR_B/bass-open.port && ! -e $DIR_B/bass-wrong.port ]] \
  && ok "no replica for a peer without credentials nor for unknown keys" || bad "an unauthenticated mirror got a replica: $(ls "$DIR_B")"
grep -q "it answers TCP but no Zenoh session came up: credentials" "$WORK/wrong-mirror.log" \
  && ok "the mirror with unknown keys says why" || bad "the wrong-key mirror said: $(tail -3 "$WORK/wrong-mirror.log")"
kill "$OPEN" "$WRONG" 2>/dev/null || true
PW2=$($BF --print-pair-password "$C/ws2.cred" ws2 robot); echo "$PW2" >"$C/pw2"
inC timeout 20 python3 $S try "$EP_C" ws2 "$PW2" && ok "the check can see a session: ws2 with its own pair password is admitted by the robot" \
  || bad "ws2's own identity was not admitted by the robot"

echo "== a trusted colleague: no identity it holds gets into ws1; what it puts through the robot never reaches a replica"
TRY=()
for pair in "ws2 robot" "robot ws2"; do
  pw=$($BF --print-pair-password "$C/ws2.cred" $pair)
  for user in robot ws1 ws2; do TRY+=("$user" "$pw"); done
done
L=$(inB timeout 60 python3 $S pairs "$WS1_EP" "${TRY[@]}") || true
[[ $(field "$L" admitted) == "[]" && $(field "$L" tried) == 6 ]] \
  && ok "ws1's mirror: the 6 identity/password pairs ws2 can make, none admitted" || bad "ws2 into ws1's mirror: $L"
# ws2 sniffs a real chunk at the robot and puts 200 well-formed chunks of the real instance and
# epoch at the next frames (0x41414141), with a liveliness token of the real instance.
J_BG=$WORK/forge-read.json
( reader $((RATE * 6)) 30 >"$J_BG" || true ) &
RD=$!
F=$(inC timeout 40 python3 $S forge "$EP_C" "$PW2" "$EP_C" "$PW2" ws2 bass src 200 1) || true
wait $RD
[[ $(field "$F" sniffed) == True && $(field "$F" put) == 200 ]] && ok "ws2 put 200 forged chunks at the robot" || bad "forge: $F"
check_exact "$(cat "$J_BG")" "replica read while ws2 forged through the robot (no 0x41414141 frame)"

# ws1 also trusts ws2 (a shared lab); its mirror then admits ws2 directly. Without the access
# control bass adds (BASS_BRIDGE_NO_ACL, tests only) the forged chunks arrive and the
# signatures stop them; with it they are dropped at the door. Either way: not one frame.
$BB credentials "$C/ws1.cred" --trust "$C/ws2.pub" 2>/dev/null
$BB credentials "$C/ws2.cred" --trust "$C/ws1.pub" 2>/dev/null
PW21=$($BF --print-pair-password "$C/ws2.cred" ws2 ws1)
for acl in off on; do
  port=$([[ $acl == on ]] && echo 7451 || echo 7450)
  envs=(); [[ $acl == off ]] && envs=(BASS_BRIDGE_NO_ACL=1)
  "${IN_B[@]}" "${envs[@]}" $BB mirror --source src --name "lab-$acl" --connect "$EP" --listen "tcp/[$ADDR_B]:$port" \
    --no-scouting --peer robot --source-identity robot --credentials "$C/ws1.cred" --status-file "$DIR_B/lab-$acl.json" \
    >>"$WORK/mirror-lab-$acl.log" 2>&1 &
  PIDS+=($!)
  wait_port "$DIR_B" "lab-$acl" || bad "mirror lab-$acl never made its replica"
  ( inB timeout 35 "$BIN/examples/pattern_reader" "lab-$acl" $((RATE * 6)) 30 >"$WORK/lab-$acl.json" || true ) &
  RD=$!
  F=$(inB timeout 40 python3 $S forge "tcp/[$ADDR_B]:$port" "$PW21" "$EP" "$(cat "$C/pw2")" ws2 bass src 200 1) || true
  wait $RD; sleep 1.2
  FORGED=$(status forged_messages "$DIR_B/lab-$acl.json")
  [[ $(field "$F" put) == 200 ]] || bad "forge into lab-$acl: $F"
  if [[ $acl == off ]]; then
    (( FORGED >= 200 )) && ok "no ACL: ws2's 200 chunks reached the mirror and all were refused as unsigned ($FORGED forged)" \
      || bad "no ACL: only $FORGED of 200 counted forged"
  else
    [[ $FORGED == 0 ]] && ok "bass's ACL: none of ws2's 200 chunks reached the mirror" || bad "ACL: $FORGED reached the mirror"
  fi
  check_exact "$(cat "$WORK/lab-$acl.json")" "replica lab-$acl while ws2 forged into it"
done

echo "== remote control: authorized per identity, every request logged"
RC=0; OUT=$(inA timeout 10 $BB serve --name src --listen "tcp/[::1]:7462" --no-scouting --allow-control 2>&1) || RC=$?
[[ $RC == 2 ]] && grep -q "needs the identities allowed" <<<"$OUT" && ok "--allow-control without names refused: ${OUT:13:80}" || bad "bare --allow-control (exit $RC): $OUT"
OUT=$(inB timeout 20 "$BIN/bass" --name rep status 2>&1) && grep -q "capturing" <<<"$OUT" \
  && ok "ws1 (allowed) gets the robot's Status" || bad "ws1's status: $OUT"
"${IN_C[@]}" $BB mirror --source src --name rep2 --connect "$EP_C" --no-scouting --credentials "$C/ws2.cred" --peer robot \
  --source-identity robot >>"$WORK/mirror-ws2.log" 2>&1 &
PIDS+=($!)
wait_port "$DIR_C" rep2 || bad "ws2's mirror never made its replica"
RC=0; OUT=$(inC timeout 20 "$BIN/bass" --name rep2 stop 2>&1) || RC=$?
[[ $RC != 0 ]] && grep -q '"ws2" is not allowed to control' <<<"$OUT" && ok "ws2 (not named) is refused: Stop not done" || bad "ws2's stop (exit $RC): $OUT"
OUT=$(inA timeout 10 "$BIN/bass" --name src status 2>&1)
grep -q capturing <<<"$OUT" && ok "the robot still captures" || bad "robot after ws2's stop: $OUT"
grep -q 'remote control from "ws1": Status: status' "$WORK/serve.log" && grep -q 'remote control refused: "ws2" is not allowed to control this broker.*Stop' "$WORK/serve.log" \
  && ok "serve's log names each request's identity, request and outcome" || bad "serve's log: $(grep 'remote control' "$WORK/serve.log")"

echo "== no secret in any output"
kill $SERVE $MIRROR 2>/dev/null || true; wait $SERVE $MIRROR 2>/dev/null || true
"${IN_A[@]}" env BASS_LOG=trace $BB serve --name src --listen "$EP" --no-scouting --credentials "$C/robot.cred" \
  --allow-control ws1 >"$WORK/serve-trace.log" 2>&1 &
SERVE=$!; PIDS+=($SERVE)
"${IN_B[@]}" env BASS_LOG=trace $BB mirror --source src --name rep --connect "$EP" --no-scouting --peer robot \
  --credentials "$C/ws1.cred" --status-file "$DIR_B/status.json" >"$WORK/mirror-trace.log" 2>&1 &
MIRROR=$!; PIDS+=($MIRROR)
wait_replica
inB timeout 20 "$BIN/bass" --name rep status >/dev/null 2>&1 || true
sleep 2
printf '{ transport: { auth: { usrpwd: { user: "ws1", password: "pasted-Secret-0123456789" } } }, oops }\n' >"$WORK/bad1.json5"
printf '{ transport: { auth: { usrpwd: { user: 7, password: "pasted-Secret-0123456789" } } } }\n' >"$WORK/bad2.json5"
for b in bad1 bad2; do
  RC=0; inA timeout 10 $BB serve --name src --zenoh-config "$WORK/$b.json5" --listen "tcp/[::1]:7463" >"$WORK/$b.log" 2>&1 || RC=$?
  [[ $RC == 2 ]] && grep -q "$b.json5: not a valid Zenoh configuration" "$WORK/$b.log" || bad "$b: exit $RC: $(cat "$WORK/$b.log")"
done
SECRETS=($SEEDS pasted-Secret-0123456789)
for f in ws1.cred:ws1:robot ws1.cred:robot:ws1 ws1.cred:ws1:ws2 ws2.cred:ws2:robot ws2.cred:robot:ws2 ws2.cred:ws2:ws1; do
  IFS=: read -r file from to <<<"$f"; SECRETS+=("$($BF --print-pair-password "$C/$file" "$from" "$to")")
done
OUTPUTS=("$WORK/serve-trace.log" "$WORK/mirror-trace.log" "$WORK/bad1.log" "$WORK/bad2.log" "$DIR_B/status.json" "$WORK"/mirror*.log "$WORK/serve.log")
for p in $SERVE $MIRROR; do tr '\0' '\n' <"/proc/$p/cmdline" >"$WORK/cmdline.$p"; tr '\0' '\n' <"/proc/$p/environ" >"$WORK/environ.$p"; OUTPUTS+=("$WORK/cmdline.$p" "$WORK/environ.$p"); done
HITS=0; for sct in "${SECRETS[@]}"; do HITS=$((HITS + $(cat "${OUTPUTS[@]}" | grep -cF -- "$sct" || true))); done
LINES=$(cat "$WORK/serve-trace.log" "$WORK/mirror-trace.log" | wc -l); RED=$(cat "$WORK/serve-trace.log" "$WORK/mirror-trace.log" | grep -c '<redacted>' || true)
[[ $HITS == 0 ]] && (( LINES > 1000 && RED > 0 )) \
  && ok "${#SECRETS[@]} secrets in none of ${#OUTPUTS[@]} outputs ($LINES trace lines, $RED with a secret redacted; config errors name the file only)" \
  || bad "$HITS secret occurrences ($LINES trace lines, $RED redacted)"
rig_done
