#!/usr/bin/env bash
# Network case "restart" (issue 20 item 5: no zero presented as audio).
#  a. The README's C program (README.md, readme-c-begin), reading 12 000 frames from frame 1
#     right after an upstream `bass acquire` with new parameters, gets on the replica exactly
#     what it gets on the source's port: the same n, loss and samples (a checksum). serve sends
#     each new acquisition from its oldest frame still in the window, so the replica starts at
#     frame 1 rather than where serve happened to reopen.
#     The same when serve starts 0.5 s after the Acquire (serve started mid-stream).
#  b. A mirror started mid-stream: its replica starts at the source's live edge F; a reader
#     from frame 1 gets frames 1..F-1 reported as loss by the library (loss = F-1, the first
#     frame delivered is F), never as zero frames, then every sample right.
#  c. SIGTERM ends serve within a second while its link is down (a put blocked on a dead link).
# tests/bridge/lib.sh has the rig.
source "$(dirname "$0")/../lib.sh"
rig_up

echo "== the README's C program, built for the source's port and for the replica"
C=$WORK/c; mkdir -p "$C"
# The block between the readme-c markers, without its ``` fences.
awk '/readme-c-begin/ {f = 1; next} /readme-c-end/ {f = 0} f' README.md | sed '1d;$d' >"$C/readme.c"
grep -q 'bass_port_open("default"' "$C/readme.c" || { bad "README's C program not found"; rig_done; }
# Two changes only: the port's name, and a checksum of the samples after its output line.
sed -e 's/bass_port_open("default"/bass_port_open(PORT_NAME/' \
    -e '/(unsigned long long)nfr);/a\
    { unsigned long long h = 1469598103934665603ull;\
      for (size_t i = 0; i < n; i++) {\
          h = (h ^ (uint32_t)left[i]) * 1099511628211ull;\
          h = (h ^ (uint32_t)right[i]) * 1099511628211ull;\
      }\
      printf("checksum %016llx\\n", h); }' "$C/readme.c" >"$C/prog.c"
for p in src rep; do
  gcc -std=c11 -Wall -Wextra -Wpedantic -Werror -I include -DPORT_NAME="\"$p\"" "$C/prog.c" \
    -L "$BIN" -lbassclient -Wl,-rpath,"$BIN" -o "$C/prog-$p"
done
ok "README program compiled with -Wall -Wextra -Wpedantic -Werror (for src and rep)"

# same_as_source LABEL: the README program read the same from the replica ($REPLICA) as from
# the source ($LOCAL). Under load Zenoh may drop a chunk of the backlog burst (serve's puts use
# CongestionControl::Drop, see bridge/src/net.rs); the mirror then publishes those frames as
# GAP (zeros, flagged, counted lost upstream). That alone may make the samples differ: the
# pattern reader then checks frames 1..12000 of the replica one by one — every frame the
# pattern, or zeros flagged GAP — and the n/loss/next-frame line must still be the same.
same_as_source() {
  if [[ -n $REPLICA && $REPLICA == "$LOCAL" ]]; then
    ok "$1: the same n, loss, next frame and samples as on the source ($(tail -1 <<<"$REPLICA"))"
    return
  fi
  local j; j=$(reader 12000 10 --from 1) || true
  if [[ -n $REPLICA && $(grep -v '^checksum' <<<"$REPLICA") == "$(grep -v '^checksum' <<<"$LOCAL")" && -n $j ]] \
     && [[ $(field "$j" bad) == 0 && $(field "$j" gap) -gt 0 ]]; then
    ok "$1: the same n, loss and next frame; the samples differ only in $(field "$j" gap) GAP frames (zeros, flagged) where the network dropped chunks: $j"
  else
    bad "$1 differs from the source: replica [$REPLICA] source [$LOCAL] pattern check [$j]"
  fi
}

start_source; start_serve; start_mirror; wait_replica
new_replicas() { grep -c 'new replica' "$WORK/mirror.log" || true; }
more_replicas_than() { (( $(new_replicas) > $1 )); }
# The mirror makes at most one new replica a second: let the first one age.
sleep 1.5

echo "== a. upstream Acquire with new parameters; the README program from frame 1, local and replica"
N0=$(new_replicas)
# 16 kHz, 320-frame chunks, 300 chunks: a 6 s window, so frames 1..12000 are still on both
# ports when the programs read them (they wait for frame 12000, 0.75 s in).
inA "$BIN/bass" --name src acquire sim:pattern --rate 16000 --frames 320 --chunks 300 --channels 2 >/dev/null
LOCAL=$(inA timeout 20 "$C/prog-src" 2>&1) || true
wait_for 10 more_replicas_than "$N0" || bad "no new replica after the upstream Acquire"
REPLICA=$(inB timeout 20 "$C/prog-rep" 2>&1) || true
echo "  source:  $(tr '\n' ' ' <<<"$LOCAL")"
echo "  replica: $(tr '\n' ' ' <<<"$REPLICA")"
grep -q '^12000 frames, 0 lost, next frame 12001$' <<<"$LOCAL" \
  && ok "source: 12000 frames from frame 1, 0 lost" || bad "source read: $LOCAL"
same_as_source "replica"

echo "== a2. serve started 0.5 s after an upstream Acquire (mid-stream): the same, from frame 1"
kill -TERM $SERVE 2>/dev/null || true; wait $SERVE 2>/dev/null || true
# At most one new replica a second in the mirror.
sleep 1
N0=$(new_replicas)
inA "$BIN/bass" --name src acquire sim:pattern --rate 16000 --frames 320 --chunks 300 --channels 2 >/dev/null
LOCAL=$(inA timeout 20 "$C/prog-src" 2>&1) || true
start_serve
wait_for 10 more_replicas_than "$N0" || bad "no new replica after serve's restart"
REPLICA=$(inB timeout 20 "$C/prog-rep" 2>&1) || true
echo "  replica starts at frame $(grep 'new replica' "$WORK/mirror.log" | tail -1 | grep -o 'first=[0-9]*' | cut -d= -f2)"
echo "  source:  $(tr '\n' ' ' <<<"$LOCAL")"
echo "  replica: $(tr '\n' ' ' <<<"$REPLICA")"
grep -q '^12000 frames, 0 lost, next frame 12001$' <<<"$LOCAL" \
  && ok "source: 12000 frames from frame 1, 0 lost" || bad "source read: $LOCAL"
same_as_source "replica of a serve started mid-stream"
sleep 1

echo "== b. a mirror started mid-stream; a reader from frame 1 on its replica"
kill -TERM $MIRROR 2>/dev/null || true; wait $MIRROR 2>/dev/null || true
sleep 1
N0=$(new_replicas)
start_mirror
wait_for 10 more_replicas_than "$N0" || bad "the restarted mirror made no replica"
F=$(grep 'new replica' "$WORK/mirror.log" | tail -1 | grep -o 'first=[0-9]*' | cut -d= -f2)
if [[ -z $F ]] || (( F <= 1 )); then
  bad "the replica's first frame ($F) is not mid-stream"
else
  echo "  replica starts at frame $F"
  # pattern_reader counts zero frames it cannot tell GAP as lost: the library's own loss
  # (reported_loss) and the first frame it delivered tell zeros from loss.
  J=$(inB timeout 30 "$BIN/examples/pattern_reader" rep $((F - 1 + 32000)) 20 --from 1) || true
  check_exact "$J" "mid-stream replica read from frame 1"
  [[ $(field "$J" reported_loss) == $((F - 1)) && $(field "$J" first_delivered) == "$F" ]] \
    && ok "frames 1..$((F - 1)) before the replica's start: reported as loss $((F - 1)), first frame delivered $F" \
    || bad "frames before the replica's start (F=$F): $J"
  [[ $(field "$J" gap) == 0 && $(field "$J" bad) == 0 ]] \
    && ok "no zero frame delivered as audio or as GAP before the start" || bad "zeros before the start: $J"
fi

echo "== c. SIGTERM ends serve within a second while its link is down"
ip -n "$NS_A" link set vA down
# Long enough for the queue to fill and a put to block on the dead link.
sleep 4
T0=$(date +%s%N)
kill -TERM $SERVE
while kill -0 $SERVE 2>/dev/null && (( $(date +%s%N) - T0 < 3000000000 )); do sleep 0.02; done
MS=$(( ($(date +%s%N) - T0) / 1000000 ))
if kill -0 $SERVE 2>/dev/null; then bad "serve still running ${MS} ms after SIGTERM"
elif (( MS <= 1000 )); then ok "serve ended ${MS} ms after SIGTERM with its link down"
else bad "serve took ${MS} ms to end after SIGTERM (limit 1000)"; fi
ip -n "$NS_A" link set vA up

rig_done
