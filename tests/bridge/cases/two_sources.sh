#!/usr/bin/env bash
# Network case "two_sources" (issue 20 item 6): two robots serve the same broker name `src` on
# one network — here two bassd + serve pairs in namespace A under two runtime directories,
# the second serve connected to the first, one mirror in B connected to both.
#  - each serve logs an error naming both instances (and the other's Zenoh id once known),
#    rate-limited, and its published state (the `info` queryable) carries the conflict;
#  - both keep serving; the mirror reports two sources and follows one of them: the replica
#    has no phantom loss (every sample right, no GAP, no loss, no gap frames in its status).
# tests/bridge/lib.sh has the rig.
source "$(dirname "$0")/../lib.sh"
rig_up
EP2="tcp/[$ADDR_A]:7449"
IN_A2=(ip netns exec "$NS_A" env BASS_RUNTIME_DIR="$DIR_C")

start_source
"${IN_A2[@]}" "$BIN/bassd" --name src --rt-priority 0 --acquire sim:pattern --rate $RATE \
  --frames $NFPC --chunks $NCOP --channels 2 >>"$WORK/bassd2.log" 2>&1 &
PIDS+=($!)
wait_port "$DIR_C" src
start_serve
"${IN_A2[@]}" "$BIN/bass-bridge" serve --name src --listen "$EP2" --connect "$EP" --no-scouting \
  "${INSECURE[@]}" >>"$WORK/serve2.log" 2>&1 &
SERVE2=$!; PIDS+=($SERVE2)
start_mirror --connect "$EP2"
wait_replica

# instance=… and zid=… of a serve's "serving" line (empty when not there).
ids() { grep -m1 ' serving ' "$1" | grep -o "$2=[0-9a-f]*" | cut -d= -f2 || true; }
# Under load the second serve may start after the replica exists: wait for both.
wait_for 20 grep -q ' serving ' "$WORK/serve.log" || bad "serve 1 never said it was serving"
wait_for 20 grep -q ' serving ' "$WORK/serve2.log" || bad "serve 2 never said it was serving"
I1=$(ids "$WORK/serve.log" instance); Z1=$(ids "$WORK/serve.log" zid)
I2=$(ids "$WORK/serve2.log" instance); Z2=$(ids "$WORK/serve2.log" zid)
echo "  serve 1: instance $I1, Zenoh id $Z1; serve 2: instance $I2, Zenoh id $Z2"
[[ -n $I1 && -n $I2 && $I1 != "$I2" ]] || bad "instance ids not found: '$I1' '$I2'"

echo "== each serve names both instances, and the other's Zenoh id, in an error"
says_conflict() { # LOG OTHER_INSTANCE OTHER_ZID OWN_INSTANCE
  # The last grep reads all its input (no -q): under pipefail an early exit would fail the pipe.
  grep 'ERROR' "$1" | grep 'two sources with one name' | grep "$2" | grep "$3" | grep "$4" >/dev/null
}
for k in 1 2; do
  if [[ $k == 1 ]]; then LOG=$WORK/serve.log; O=$I2; OZ=$Z2; OWN=$I1; else LOG=$WORK/serve2.log; O=$I1; OZ=$Z1; OWN=$I2; fi
  if wait_for 10 says_conflict "$LOG" "$O" "$OZ" "$OWN"; then
    ok "serve $k: error naming instance $O (Zenoh id $OZ) and itself ($OWN)"
  else bad "serve $k: no error naming both instances: $(grep -i 'two sources' "$LOG" | tail -2)"; fi
done

echo "== the published state carries the conflict (the info queryable of both serves)"
INFO=$(inB timeout 20 python3 - "$EP" "$EP2" <<'PY'
import json, sys, time
import zenoh
conf = zenoh.Config.from_json5(json.dumps({
    "mode": "peer", "connect": {"endpoints": sys.argv[1:]}, "listen": {"endpoints": []},
    "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
}))
with zenoh.open(conf) as s:
    deadline = time.monotonic() + 10
    while len(list(s.info.peers_zid())) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    # Every queryable, every reply (both serves answer on the same key).
    replies = s.get("bass/src/info", target=zenoh.QueryTarget.ALL,
                    consolidation=zenoh.ConsolidationMode.NONE, timeout=5)
    for r in replies:
        if r.ok is not None:
            st = json.loads(r.ok.payload.to_bytes())
            print(json.dumps({"instance": st.get("instance"), "conflict": st.get("conflict")}))
PY
) || true
echo "$INFO" | sed 's/^/  /'
for k in 1 2; do
  if [[ $k == 1 ]]; then OWN=$I1; O=$I2; else OWN=$I2; O=$I1; fi
  if python3 -c '
import json, sys
own, other = sys.argv[1], sys.argv[2]
rows = [json.loads(l) for l in sys.stdin if l.strip()]
sys.exit(0 if any(r["instance"] == own and r["conflict"] and other in r["conflict"] for r in rows) else 1)
' "$OWN" "$O" <<<"$INFO"; then ok "serve $k's state: conflict with instance $O"
  else bad "serve $k's state has no conflict naming $O: $INFO"; fi
done

echo "== both keep serving; the mirror follows one source without phantom loss"
J=$(reader $((RATE * 4)) 30) || true
check_exact "$J" "replica with two sources"
[[ $(field "$J" gap) == 0 && $(field "$J" lost) == 0 && $(field "$J" restarts) == 0 ]] \
  && ok "no phantom loss: no GAP, no loss, no restart in 4 s" || bad "phantom loss with two sources: $J"
sleep 1.5
[[ $(status gap_frames_lost) == 0 ]] && ok "mirror: gap_frames_lost 0" || bad "mirror: gap_frames_lost $(status gap_frames_lost)"
TS=$(status two_sources 2>/dev/null || echo missing)
grep -q "$I1" <<<"$TS" && grep -q "$I2" <<<"$TS" && ok "mirror reports two sources: $TS" \
  || bad "mirror's status does not name both sources: two_sources=$TS"
kill -0 $SERVE && kill -0 $SERVE2 && ok "both serves still running" || bad "a serve ended"

echo "== the error is rate-limited"
N1=$(grep -c 'two sources with one name' "$WORK/serve.log" || true)
N2=$(grep -c 'two sources with one name' "$WORK/serve2.log" || true)
(( N1 <= 3 && N2 <= 3 )) && ok "error lines: $N1 and $N2 (first sight, then the Zenoh id)" \
  || bad "too many error lines: $N1 and $N2"

rig_done
