#!/usr/bin/env bash
# Network case "basic": the clean link, Python on the replica, stalls of serve and mirror, a 3 s link outage, an upstream
# Acquire, bassd killed, serve and mirror restarted, a congested link, deterministic faults
# (the test-only bass-bridge-faults), batched messages, a real-time bridge (--rt-priority), remote control, the iceoryx2 export,
# the clock estimate, TLS with client certificates. tests/bridge/lib.sh has the rig.
source "$(dirname "$0")/../lib.sh"
rig_up

echo "== 1. clean link"
start_source; start_serve; start_mirror; wait_replica
J=$(reader $((RATE * 3)) 20) || true
check_exact "$J" "clean link"
[[ $(field "$J" gap) == 0 && $(field "$J" lost) == 0 ]] && ok "clean link: no gap, no loss" || bad "clean link lost frames: $J"

echo "== 2. C ABI through Python on the replica (unchanged client code)"
if inB env PYTHONPATH="$ROOT/python" BASS_LIB="$BIN/libbassclient.so" timeout 20 python3 - <<'PY'
import bass, numpy as np
with bass.Port("rep") as p:
    n = 0
    for b in p.blocks(4800, count=5, timeout=5):
        f = np.arange(b.first_frame, b.first_frame + 4800, dtype=np.uint64)
        assert b.loss == 0, b.loss
        for c, got in enumerate((b.left, b.right)):
            wrong = np.flatnonzero(got != bass.pattern_expected(f, c))
            assert wrong.size == 0, (
                f"block {n} (frames {b.first_frame}..{b.next_frame - 1}), channel {c}: {wrong.size} frames wrong, "
                f"first at frame {int(f[wrong[0]])} (got {int(got[wrong[0]])}, want "
                f"{int(bass.pattern_expected(f[wrong[0]:wrong[0] + 1], c)[0])}), "
                f"{int((got[wrong] == 0).sum())} of them zero, last wrong frame {int(f[wrong[-1]])}")
        n += 1
    assert n == 5
print("python: 5 blocks of 4800 frames match the pattern")
PY
then ok "python reader on the replica"; else bad "python reader on the replica"; cat "$DIR_B/status.json" || true; tail -20 "$WORK/mirror.log"; fi

echo "== 2b. serve, then mirror, stopped 200 ms (a scheduling stall): nothing lost"
# Shorter than serve's live patience (250 ms, bridge/src/patience.rs) and the 0.5 s window:
# the port holds the frames meanwhile. (serve used to drop what found its queue full: a
# 30 ms stall of serve put GAP frames into the replica.)
reader $((RATE * 3)) 20 > "$WORK/r2b.json" & R=$!
sleep 0.8; kill -STOP $SERVE; sleep 0.2; kill -CONT $SERVE
sleep 0.8; kill -STOP $MIRROR; sleep 0.2; kill -CONT $MIRROR
wait $R || true; J=$(cat "$WORK/r2b.json")
check_exact "$J" "stalls of 200 ms"
[[ $(field "$J" gap) == 0 && $(field "$J" lost) == 0 ]] && ok "stalls of 200 ms: no gap, no loss" || bad "stalls of 200 ms lost frames: $J"

echo "== 3. link down 3 s, then up (no restart of anything)"
reader $((RATE * 9)) 30 > "$WORK/r3.json" & R=$!
sleep 2; ip -n "$NS_A" link set vA down; sleep 3; ip -n "$NS_A" link set vA up
wait $R || true; J=$(cat "$WORK/r3.json")
check_exact "$J" "link outage"
(( $(field "$J" gap) > 0 )) && ok "link outage: the outage is GAP frames at their indices ($(field "$J" gap) frames)" || bad "link outage left no gap: $J"
(( $(field "$J" delivered) > 0 )) && kill -0 $SERVE && kill -0 $MIRROR && ok "link outage: recovered without a restart" || bad "no recovery: $J"

echo "== 4. upstream Acquire with new parameters (new epoch)"
reader $((RATE * 4)) 20 > "$WORK/r4.json" & R=$!
sleep 1; inA "$BIN/bass" --name src acquire sim:pattern --rate $RATE --frames 240 --chunks 100 --channels 2 >/dev/null
wait $R || true; J=$(cat "$WORK/r4.json")
check_exact "$J" "new epoch"
(( $(field "$J" restarts) >= 1 )) && ok "new epoch: readers saw RESTARTED and reopened" || bad "no restart seen: $J"

echo "== 5. bassd killed upstream: replica in error, recovers with bassd and an Acquire"
reader $((RATE * 4)) 30 > "$WORK/r5.json" & R=$!
sleep 1; kill -9 $BASSD 2>/dev/null || true; sleep 2
start_source
wait $R || true; J=$(cat "$WORK/r5.json")
check_exact "$J" "bassd killed"
(( $(field "$J" errors) >= 1 )) && ok "bassd killed: readers of the replica saw a device error" || bad "no error seen: $J"
(( $(field "$J" restarts) >= 1 )) && ok "bassd killed: recovered on the new acquisition" || bad "no recovery: $J"

echo "== 6. serve killed and restarted (same epoch: port kept, gap filled)"
reader $((RATE * 5)) 30 > "$WORK/r6.json" & R=$!
sleep 1; kill $SERVE 2>/dev/null || true; wait $SERVE 2>/dev/null || true; sleep 1; start_serve
wait $R || true; J=$(cat "$WORK/r6.json")
check_exact "$J" "serve restarted"
# serve was down 1 s, longer than the 0.5 s window: what the restarted serve could not send
# any more (it sends from the oldest frame still on the port) is GAP, or loss for a reader.
[[ $(field "$J" restarts) == 0 ]] && (( $(field "$J" gap) + $(field "$J" lost) > 0 )) && ok "serve restarted: same replica port, the gap marked" || bad "serve restart: $J"

echo "== 7. mirror restarted (old readers: stopped; the new replica starts at the live edge)"
reader $((RATE * 4)) 30 > "$WORK/r7.json" & R=$!
sleep 1; kill $MIRROR 2>/dev/null || true; wait $MIRROR 2>/dev/null || true; start_mirror
wait $R || true; J=$(cat "$WORK/r7.json")
check_exact "$J" "mirror restarted"
(( $(field "$J" restarts) >= 1 )) && ok "mirror restarted: readers moved to the new replica" || bad "mirror restart: $J"
sleep 1.5
(( $(status chunks_written) > 0 )) && ok "mirror restarted: new replica written (epoch $(status replica_epoch))" || bad "mirror status"

echo "== 8. congested link (tbf below the stream's rate): the bridge drops and counts, the replica marks"
ip netns exec "$NS_A" tc qdisc add dev vA root tbf rate 1mbit burst 32kbit latency 200ms
reader $((RATE * 4)) 40 > "$WORK/r8.json" & R=$!
wait $R || true; J=$(cat "$WORK/r8.json")
ip netns exec "$NS_A" tc qdisc del dev vA root
check_exact "$J" "congested link"
# Long runs of dropped chunks are published as GAP jumps; a reader lapped by one counts loss.
(( $(field "$J" gap) + $(field "$J" lost) > 0 )) && ok "congested link: what the bridge dropped reached the reader as GAP frames or loss" || bad "congestion left no mark: $J"
sleep 1.5
# Who drops depends on the buffers: serve's queue once a chunk is 250 ms behind (counted in
# gap_frames_source), or Zenoh's after its 50 ms wait (a sequence gap); the mirror counts both.
GL=$(status gap_frames_lost); GS=$(status gap_frames_source)
(( GL > 0 && GS <= GL )) && ok "congested link: the drops reported ($GL frames lost upstream, $GS of them by serve)" || bad "congested link: gap_frames_lost=$GL gap_frames_source=$GS"

echo "== 9. deterministic faults by sequence number (drop, duplicate, reorder, delay)"
kill $SERVE 2>/dev/null || true; wait $SERVE 2>/dev/null || true
kill $MIRROR 2>/dev/null || true; wait $MIRROR 2>/dev/null || true; rm -f "$DIR_B/status.json"
SERVE_BIN=("$BIN/bass-bridge-faults" --fault drop=300,dup=320,reorder=340,delay=360)
start_serve; SERVE_BIN=(); sleep 0.5; start_mirror
reader $((RATE * 6)) 30 > "$WORK/r9.json" & R=$!
wait $R || true; J=$(cat "$WORK/r9.json"); sleep 1.5
check_exact "$J" "fault injection"
LD=$(status late_or_duplicate); GL=$(status gap_frames_lost)
[[ $LD == 3 && $GL == $((3 * NFPC)) ]] && ok "faults: 3 late/duplicate chunks dropped, 3 chunks of GAP frames" || bad "faults: late_or_duplicate=$LD gap_frames_lost=$GL"

echo "== 9b. four chunks per Zenoh message (serve --chunks-per-message 4)"
kill $SERVE 2>/dev/null || true; wait $SERVE 2>/dev/null || true
start_serve --chunks-per-message 4; sleep 1.5
J=$(reader $((RATE * 2)) 20) || true
check_exact "$J" "batched messages"
[[ $(field "$J" gap) == 0 && $(field "$J" lost) == 0 ]] && ok "batched messages: no gap, no loss" || bad "batched messages lost frames: $J"

echo "== 9c. serve and mirror --rt-priority 7: the data path's threads (Zenoh's included) at SCHED_FIFO 7, data exact"
kill $SERVE $MIRROR 2>/dev/null || true; wait $SERVE $MIRROR 2>/dev/null || true; rm -f "$DIR_B/status.json"
start_serve --rt-priority 7; sleep 0.5; start_mirror --rt-priority 7; wait_replica
J=$(reader $((RATE * 2)) 20) || true
check_exact "$J" "real-time bridge"
[[ $(field "$J" gap) == 0 && $(field "$J" lost) == 0 ]] && ok "real-time bridge: no gap, no loss" || bad "real-time bridge lost frames: $J"
# Every thread but the shutdown watchdog (made before the option is applied; it only acts at exit).
for p in $SERVE $MIRROR; do
  T=$(ps -L -o cls=,rtprio=,comm= -p "$p" | grep -v 'shutdown-dead')
  if [[ -n $T ]] && ! grep -qv '^ *FF *7 ' <<<"$T"; then
    ok "real-time bridge: pid $p, all $(wc -l <<<"$T") threads of the data path (Zenoh's included) SCHED_FIFO 7"
  else bad "real-time bridge: pid $p threads: $(tr '\n' ';' <<<"$T")"; fi
done

echo "== 10. remote control: refused without serve --allow-control, forwarded with it"
# From here on serve and mirror run with credentials (remote control needs them): chunks,
# states, clock answers and control replies signed, control requests signed by ws1.
C=$WORK/cred; mkdir -p "$C"
"$BIN/bass-bridge" credentials "$C/robot.cred" --user robot 2>/dev/null
"$BIN/bass-bridge" credentials "$C/ws1.cred" --user ws1 --trust "$C/robot.pub" 2>/dev/null
"$BIN/bass-bridge" credentials "$C/robot.cred" --trust "$C/ws1.pub" 2>/dev/null
kill $SERVE $MIRROR 2>/dev/null || true; wait $SERVE $MIRROR 2>/dev/null || true
INSECURE=()
start_serve --credentials "$C/robot.cred"; start_mirror --credentials "$C/ws1.cred"; sleep 1.5
# Requests the mirror forwards (Stop, Acquire, ListDevices) are refused by a serve without
# --allow-control; Status is the mirror's own answer (issue 33), without the source's live one.
if OUT=$(inB timeout 20 "$BIN/bass" --name rep devices 2>&1); then bad "devices without --allow-control succeeded: $OUT"
elif grep -q "allow-control" <<<"$OUT"; then ok "remote control refused by default ($(tail -1 <<<"$OUT"))"
else bad "unexpected refusal: $OUT"; fi
OUT=$(inB timeout 20 "$BIN/bass" --name rep status --json 2>&1) || OUT="exit $?: $OUT"
python3 -c 'import json, sys; j = json.loads(sys.argv[1]); r = j["replica"]
assert r["source"] == "src" and r["link_up"] and r["source_status"] is None, r' "$OUT" 2>/dev/null \
  && ok "Status without --allow-control: the mirror's own answer, no live source status" || bad "status without --allow-control: $OUT"
kill $SERVE 2>/dev/null || true; wait $SERVE 2>/dev/null || true; start_serve --credentials "$C/robot.cred" --allow-control ws1; sleep 1.5
# With it the source's live Status is added (asked for 0.5 s at most: polled until the
# restarted serve's control answers).
live() { inB timeout 20 "$BIN/bass" --name rep status --json 2>/dev/null | python3 -c 'import json, sys
r = json.load(sys.stdin)["replica"]; s = r["source_status"]; assert s and s["state"] == 1, r'; }  # 1: capturing
wait_for 10 live && ok "Status with --allow-control adds the source's live Status (capturing)" \
  || bad "no live source status through the bridge: $(inB timeout 20 "$BIN/bass" --name rep status 2>&1 | tail -3)"
inB timeout 20 "$BIN/bass" --name rep acquire sim:pattern --rate $RATE --frames 960 --chunks 20 --channels 2 >/dev/null 2>&1 || true
OUT=$(inA timeout 10 "$BIN/bass" --name src status 2>&1)
grep -q "960 frames x 20 chunks" <<<"$OUT" && ok "Acquire from the workstation reached the robot's bassd" || bad "remote acquire: $OUT"
J=$(reader $((RATE * 2)) 20) || true
check_exact "$J" "after the remote Acquire"

echo "== 10b. a flood of remote control requests: 8 answered at once, the rest refused as busy"
# Each forwarded request is held 2 s in serve (test-only fault), so 12 requests sent at once
# are all in progress together: 8 are answered, 4 get serve's busy error, none is lost.
kill $SERVE 2>/dev/null || true; wait $SERVE 2>/dev/null || true
SERVE_BIN=("$BIN/bass-bridge-faults" --fault control-delay=2000)
start_serve --credentials "$C/robot.cred" --allow-control ws1; SERVE_BIN=(); sleep 1.5
FLOOD=()
# ListDevices is forwarded (a Status is the mirror's own answer, which waits 0.5 s at most).
for k in $(seq 12); do
  inB timeout 20 "$BIN/bass" --name rep devices >"$WORK/flood.$k" 2>&1 & FLOOD+=($!)
done
for p in "${FLOOD[@]}"; do wait "$p" || true; done
ANSWERED=$(grep -l "sim:pattern" "$WORK"/flood.* | wc -l || true); BUSY=$(grep -l "busy (8 control requests in progress)" "$WORK"/flood.* | wc -l || true)
if [[ $ANSWERED == 8 && $BUSY == 4 ]]; then ok "12 requests at once: 8 answered, 4 refused as busy"
else bad "12 requests at once: $ANSWERED answered, $BUSY busy (want 8 and 4): $(cat "$WORK"/flood.* | tr '\n' ' ' | cut -c1-600)"; fi
OUT=$(inB timeout 20 "$BIN/bass" --name rep status 2>&1) && grep -q "capturing" <<<"$OUT" \
  && ok "after the flood the next request is answered" || bad "status after the flood: $OUT"

echo "== 11. iceoryx2 export: a PyPI iceoryx2 subscriber checks frame indices and samples"
# Node and service files; iceoryx2's one 16-byte `*.global_mgmt` segment is meant to stay.
iox_files() { { ls /dev/shm; ls /tmp/iceoryx2/nodes /tmp/iceoryx2/services 2>/dev/null; } | grep iox2 | grep -vc 'global_mgmt$' || true; }
BEFORE=$(iox_files)
kill $SERVE 2>/dev/null || true; wait $SERVE 2>/dev/null || true
start_serve --iceoryx2 --credentials "$C/robot.cred"; sleep 1
if inA timeout 30 python3 tests/bridge/iox_subscriber.py src 200 20; then ok "iceoryx2: 200 chunks, every sample right"; else bad "iceoryx2 subscriber"; fi
kill -TERM $SERVE 2>/dev/null || true; wait $SERVE 2>/dev/null || true
AFTER=$(iox_files)
[[ $AFTER == "$BEFORE" ]] && ok "iceoryx2: SIGTERM left no iceoryx2 files ($AFTER before and after)" || bad "iceoryx2 files: $BEFORE before, $AFTER after"

echo "== clock offset (same machine: the true offset is 0)"
OFF=$(status clock_offset_ns); UNC=$(status clock_uncertainty_ns)
[[ $OFF != None && $UNC != None ]] && ok "clock: offset ${OFF} ns, uncertainty ${UNC} ns" || bad "no clock estimate"

echo "== 12. TLS with mutual certificates and user/password (docs/network.md, Security)"
# The configuration of docs/network.md, with certificates made here for the two namespaces.
kill $SERVE $MIRROR 2>/dev/null || true; wait $SERVE $MIRROR 2>/dev/null || true
T=$WORK/tls; mkdir -p "$T"
ec=(-newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes)
openssl req -x509 "${ec[@]}" -days 2 -subj /CN=bass-test-ca -keyout "$T/ca-key.pem" -out "$T/ca.pem" 2>/dev/null
for n in robot ws; do
  openssl req "${ec[@]}" -subj "/CN=$n" -keyout "$T/$n-key.pem" -out "$T/$n.csr" 2>/dev/null
  printf 'subjectAltName=DNS:%s.bass-test\nbasicConstraints=CA:FALSE\nkeyUsage=digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n' \
    "$n" >"$T/$n.ext"
  openssl x509 -req -in "$T/$n.csr" -CA "$T/ca.pem" -CAkey "$T/ca-key.pem" -CAcreateserial -days 2 \
    -extfile "$T/$n.ext" -out "$T/$n.pem" 2>/dev/null
done
printf 'robot:robot-secret\nws:ws-secret\n' >"$T/users.txt"
# Zenoh's TLS takes the server name from the connect endpoint and refuses an IP literal
# ("invalid dns name"): the workstation knows the robot by name, here through the
# namespace's own hosts file (`ip netns exec` mounts /etc/netns/NS/hosts over /etc/hosts).
mkdir -p "/etc/netns/$NS_B"
printf '127.0.0.1 localhost\n::1 localhost\n%s robot.bass-test\n' "$ADDR_A" >"/etc/netns/$NS_B/hosts"
tls_config() { # FILE WHO listen|connect PASSWORD ENDPOINT
  cat >"$1" <<EOF
{
  mode: "peer",
  $3: { endpoints: ["tls/$5:7448"] },
  scouting: { multicast: { enabled: false }, gossip: { enabled: false } },
  transport: {
    link: {
      tls: {
        root_ca_certificate: "$T/ca.pem",
        listen_private_key: "$T/$2-key.pem",
        listen_certificate: "$T/$2.pem",
        enable_mtls: true,
        connect_private_key: "$T/$2-key.pem",
        connect_certificate: "$T/$2.pem",
      },
    },
    auth: { usrpwd: { user: "$2", password: "$4", dictionary_file: "$T/users.txt" } },
  },
}
EOF
}
tls_config "$T/robot.json5" robot listen robot-secret "[$ADDR_A]"
tls_config "$T/ws.json5" ws connect ws-secret robot.bass-test
tls_config "$T/intruder.json5" ws connect wrong-password robot.bass-test
"${IN_A[@]}" "$BIN/bass-bridge" serve --name src --zenoh-config "$T/robot.json5" >>"$WORK/serve.log" 2>&1 &
SERVE=$!; PIDS+=($SERVE); sleep 0.5
"${IN_B[@]}" "$BIN/bass-bridge" mirror --source src --name bad --zenoh-config "$T/intruder.json5" >>"$WORK/mirror.log" 2>&1 &
BADM=$!; PIDS+=($BADM)
"${IN_B[@]}" "$BIN/bass-bridge" mirror --source src --name tls --zenoh-config "$T/ws.json5" >>"$WORK/mirror.log" 2>&1 &
MIRROR=$!; PIDS+=($MIRROR)
J=$(inB timeout 25 "$BIN/examples/pattern_reader" tls $((RATE * 2)) 20) || true
check_exact "$J" "TLS + user/password"
[[ -f $DIR_B/bass-tls.port ]] && (( $(field "$J" delivered) > 0 )) && ok "TLS: the replica is written over tls/ with mTLS" || bad "TLS replica: $J"
[[ ! -e $DIR_B/bass-bad.port ]] && ok "TLS: a workstation with a wrong password gets no audio" \
  || bad "a wrong password was accepted: $(inB timeout 5 "$BIN/bass" --name bad status 2>&1 | head -3)"
kill $BADM 2>/dev/null || true

rig_done
