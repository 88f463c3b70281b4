#!/usr/bin/env bash
# tests/replay: record -> replay -> compare, across real processes and through the C ABI.
#
# Each case records a live port with `bass record` (real bassd, real shared memory), replays
# the file with `sim:file:` under bassd, reads the replay live with tests/replay/port_dump.c
# (the C ABI, strict warnings) and checks every frame, loss, flag and timestamp against the
# WAV + sidecar with tests/replay/compare.py (its own WAV parser). The cases:
#   gap-ends  sim:xrun from frame 4001: starts on GAP chunks, ends on GAP chunks
#   late      sim:pattern with bassd stopped 0.4 s mid-recording: LATE chunks
#   loss      sim:pattern with the recorder stopped longer than the window: a loss inside
#   renumber  gap-ends replayed with --renumber: from frame 1, same flags
#   old-sidecar  gap-ends with its rows' bounds and masks taken out (an older recorder's
#             sidecar): replayed with every bound not known and no mask
# (every replay is held against its rows' flags, times, timestamp bounds and channel masks)
# and the same for `bass record --format mcap` (a rosbag2 bag directory holding one MCAP file),
# checked first by readers bass did not write (tests/replay/mcap_check.py: PyPI mcap with
# mcap-ros2-support, and rosbags), which also write what the messages say as the WAV +
# sidecar the replay is compared against:
#   mcap-gap       sim:xrun recorded beside gap-ends: the same samples and rows as its WAV
#   mcap-loss      sim:pattern with the recorder stopped: a loss inside, every sample checked
#   mcap-renumber  mcap-gap replayed from frame 1
#   mcap-refused   a replay with another chunk size is refused, naming the recording's
#   mcap-foxglove       sim:xrun recorded beside gap-ends with --foxglove-audio --channels 1,0:
#                       `bass record --check` and tests/replay/foxglove_check.py (PyPI mcap +
#                       mcap-ros2-support) hold every RawAudio message against its audio
#                       message (stamp, every sample rounded to 16 bits, GAP zeros) and the
#                       schema against Foxglove's published definition; replayed as well
#   mcap-foxglove-loss  the same beside mcap-loss (stopped with it): lost frames in no message
# and `bass record --format xdf` (FILE.xdf), checked by `bass record --check` and by PyPI
# pyxdf (tests/replay/xdf_check.py) against a WAV + sidecar recorded beside it: every sample,
# every stamp (its chunk's CLOCK_MONOTONIC + offset / rate, within 1 us), every marker:
#   xdf-gap   sim:xrun recorded beside gap-ends: the zero-filled runs as gap markers
#   xdf-loss  sim:pattern, --channels 1,0, the recorder stopped longer than the window: the
#             frames it lost as one overrun marker, not as samples
#   xdf-kill  a recorder SIGKILLed between two checkpoints: a file without footers pyxdf reads
# Assertions are on indices, samples, losses and flags; the stops only create the conditions.
set -euo pipefail
SUITE=tests/replay
source "$(dirname "$0")/../lib.sh"
top=$TOP bin=$BIN
need_built bassd bass libbassclient.so
work=$(mktemp -d -t bass-replay-tests.XXXXXX)
trap 'stop_all; rm -rf "$work"' EXIT
cc=${CC:-cc}
"$cc" -std=c11 -Wall -Wextra -Wpedantic -Werror -O2 -I "$top/include" "$top/tests/replay/port_dump.c" \
  -o "$work/port_dump" -L "$bin" -lbassclient -Wl,-rpath,"$bin" -lpthread

export BASS_RUNTIME_DIR=$work/rt
mkdir -p "$BASS_RUNTIME_DIR" "$work/rec"
BASS_LOG=warn "$bin/bassd" --rt-priority 0 --allow-device "sim:file:$work/rec/*" \
  --allow-device "sim:file-renumber:$work/rec/*" 2>>"$work/bassd.log" &
bassd_pid=$!
PIDS+=("$bassd_pid")
for _ in $(seq 400); do [[ -S "$BASS_RUNTIME_DIR/bass-default.sock" ]] && break; sleep 0.025; done
bass() { "$bin/bass" "$@"; }

# Waits (bounded) until the sidecar of $1 exists.
wait_sidecar() {
  for _ in $(seq 400); do [[ -s "$1.json" ]] && return 0; sleep 0.05; done
  echo "no sidecar for $1"; return 1
}

# replay CASE WAV [--renumber]: checks the recording (bass record --check), replays it, dumps
# what a client reads, compares.
replay() {
  local case=$1 wav=$2 extra=${3:-}
  local flag=()
  [[ -n "$extra" ]] && flag=(--renumbered)
  if ! out=$(bass record --check "$wav" 2>&1); then
    bad "$case: bass record --check: $out"; return
  fi
  if ! out=$(bass acquire "sim:file:$wav" -r 8000 --frames 100 --chunks 400 -c 2 $extra 2>&1); then
    bad "$case: the replay was refused: $out"; return
  fi
  if ! timeout 30 "$work/port_dump" default 1000 25 >"$work/$case.dump" 2>"$work/$case.err"; then
    bad "$case: port_dump: $(cat "$work/$case.err")"; return
  fi
  if out=$(python3 "$top/tests/replay/compare.py" "$wav" "$work/$case.dump" "${flag[@]}"); then
    ok "$case: $out"
  else
    bad "$case: $out"
  fi
}

# replay_mcap CASE BAG REF [--renumber]: replays the MCAP recording BAG (a bag directory or its
# .mcap file), dumps what a client reads, compares with REF (the WAV + sidecar mcap_check.py
# wrote from the messages).
replay_mcap() {
  local case=$1 bag=$2 ref=$3 extra=${4:-}
  local flag=() mode=sim:file
  [[ -n "$extra" ]] && { flag=(--renumbered); mode=sim:file-renumber; }
  if ! out=$(bass acquire "$mode:$bag" -r 8000 --frames 100 --chunks 400 -c 2 2>&1); then
    bad "$case: the replay was refused: $out"; return
  fi
  if ! timeout 30 "$work/port_dump" default 1000 25 >"$work/$case.dump" 2>"$work/$case.err"; then
    bad "$case: port_dump: $(cat "$work/$case.err")"; return
  fi
  if out=$(python3 "$top/tests/replay/compare.py" "$ref" "$work/$case.dump" "${flag[@]}"); then
    ok "$case: replay $out"
  else
    bad "$case: $out"
  fi
}

# mcap_check CASE BAG ARGS...: the independent readers' verdict on BAG.
mcap_check() {
  local case=$1; shift
  if out=$(python3 "$top/tests/replay/mcap_check.py" "$@" 2>&1); then
    ok "$case: $out"; return 0
  fi
  bad "$case: $out"; return 1
}

# sidecar_bounds WAV: the rows' bounds, in short.
sidecar_bounds() {
  python3 -c 'import json,sys; b=[r.get("bound_ns") for r in json.load(open(sys.argv[1]))["chunks"]]; print(len(b), "rows, bounds", sorted(set(b), key=str)[:6])' "$1.json"
}

# sidecar_has WAV PYTHON-EXPR: whether the expression holds of the sidecar `s`.
sidecar_has() {
  python3 -c "import json,sys; s=json.load(open(sys.argv[1])); sys.exit(0 if ($2) else 1)" "$1.json"
}

# 1. gap-ends: sim:xrun, 8000 Hz, 100-frame chunks: GAP chunks at 4001..4400 and 8501..8800.
bass acquire sim:xrun -r 8000 --frames 100 --chunks 200 -c 2 >/dev/null
gap=$work/rec/gap-ends.wav
gap_bag=$work/rec/gap-mcap
gap_xdf=$work/rec/gap.xdf
fox_bag=$work/rec/fox-mcap
bass record --format mcap "$gap_bag" --from 4001 --frames 4800 -q --json >"$work/gap-mcap.json" &
rec=$!
bass record "$gap_xdf" --from 4001 --frames 4800 -q --json >"$work/gap-xdf.json" &
rec_xdf=$!
bass record --format mcap "$fox_bag" --from 4001 --frames 4800 --channels 1,0 --foxglove-audio -q \
  --json >"$work/fox-mcap.json" &
rec_fox=$!
bass record "$gap" --from 4001 --frames 4800 -q
wait "$rec" || bad "mcap-gap: bass record --format mcap failed"
wait "$rec_xdf" || bad "xdf-gap: bass record FILE.xdf failed"
wait "$rec_fox" || bad "mcap-foxglove: bass record --format mcap --foxglove-audio failed"
if sidecar_has "$gap" 's["chunks"][0]["flags"] & 1 and s["chunks"][-1]["flags"] & 1 and s["recording"]["first_frame"] == 4001'; then
  replay gap-ends "$gap"
else
  bad "gap-ends: the recording does not start and end on GAP chunks: $(head -c 600 "$gap.json")"
fi
# The capture's bound of every chunk is in its row (compare.py then holds the replayed port's
# bound of each chunk against its row). A sim device's chunks all get the a-priori bound (one
# chunk, 12.5 ms): bounds that differ per chunk are tested in broker/tests/replay.rs and
# cli/src/record/tests.rs, from a writer that sets them.
if sidecar_has "$gap" 'all(r.get("bound_ns", 2**64) < 10**9 for r in s["chunks"])'; then
  ok "gap-ends: every row has its chunk's bound: $(sidecar_bounds "$gap")"
else
  bad "gap-ends: rows without a bound: $(sidecar_bounds "$gap")"
fi

# 1b. old-sidecar: the gap-ends recording with a sidecar of a recorder before port format 2.4
# (rows without bound_ns and masks): replayed with the bounds not known and no mask.
old=$work/rec/old-sidecar.wav
cp "$gap" "$old"
python3 -c '
import json, sys
s = json.load(open(sys.argv[1]))
for r in s["chunks"]:
    for k in ("bound_ns", "missing_channels", "unaligned_channels"):
        r.pop(k, None)
s["recording"]["file"] = sys.argv[2]
json.dump(s, open(sys.argv[2] + ".json", "w"))' "$gap.json" "$old"
replay old-sidecar "$old"
if ! grep -q "^chunk .* 18446744073709551615 0 0$" "$work/old-sidecar.dump" \
    || grep "^chunk " "$work/old-sidecar.dump" | grep -qv " 18446744073709551615 0 0$"; then
  bad "old-sidecar: a replayed chunk has a bound or a mask: $(grep -m3 '^chunk ' "$work/old-sidecar.dump")"
fi

# 2. late: bassd stopped for 0.4 s while the recorder runs: the sim device catches up in a
# burst and flags those chunks LATE.
bass acquire sim:pattern -r 8000 --frames 100 --chunks 200 -c 2 >/dev/null
late=$work/rec/late.wav
"$bin/bass" record "$late" --frames 12000 -q &
rec=$!
sleep 0.5
kill -STOP "$bassd_pid"; sleep 0.4; kill -CONT "$bassd_pid"
wait "$rec" || true
if sidecar_has "$late" 'any(r["flags"] & 8 for r in s["chunks"])'; then
  replay late "$late"
else
  bad "late: the recording has no LATE chunk (nothing to test): $(grep -c '"flags": 8' "$late.json" || true)"
fi

# 3. loss: a 1000-frame window (125 ms); the recorder stopped for 0.6 s loses frames inside
# the file.
bass acquire sim:pattern -r 8000 --frames 100 --chunks 10 -c 2 >/dev/null
loss=$work/rec/loss.wav
"$bin/bass" record "$loss" --frames 12000 -q &
rec=$!
sleep 0.4
kill -STOP "$rec"; sleep 0.6; kill -CONT "$rec"
wait "$rec" || true
if sidecar_has "$loss" 's["recording"]["lost_frames"] > 0 and len(s["losses"]) == 1'; then
  replay loss "$loss"
else
  bad "loss: the recording has no single loss inside (nothing to test): $(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["losses"])' "$loss.json")"
fi

# 4. renumber: the gap-ends recording from frame 1.
replay renumber "$gap" --renumber

# 5. MCAP: the sim:xrun recording made beside gap-ends, checked against its WAV and the
# signal, replayed from the bag directory at its indices and from frame 1.
if mcap_check mcap-gap "$gap_bag" --signal xrun --expect-gap --expect-bound --recorder "$work/gap-mcap.json" \
    --wav "$gap" --ref "$work/gap-mcap-ref.wav"; then
  replay_mcap mcap-gap "$gap_bag" "$work/gap-mcap-ref.wav"
  replay_mcap mcap-renumber "$gap_bag" "$work/gap-mcap-ref.wav" --renumber
fi

# fox_check CASE BAG ARGS...: `bass record --check` (which holds the RawAudio messages against
# the audio messages), then PyPI mcap + mcap-ros2-support's reading (foxglove_check.py).
fox_check() {
  local case=$1 bag=$2; shift 2
  if ! out=$(bass record --check "$bag" 2>&1); then
    bad "$case: bass record --check: $out"; return 1
  fi
  if [[ $out != *"RawAudio messages (pcm-s16) agree"* ]]; then
    bad "$case: bass record --check saw no RawAudio messages: $out"; return 1
  fi
  ok "$case: bass record --check: ...${out##*chunk rows}"
  if out=$(python3 "$top/tests/replay/foxglove_check.py" "$bag" "$@" 2>&1); then
    ok "$case: $out"; return 0
  fi
  bad "$case: $out"; return 1
}

# 5b. MCAP with --foxglove-audio: sim:xrun recorded beside gap-ends, channels 1 and 0; the
# RawAudio channel checked, the rest as any MCAP recording, and the file replayed (bassd
# replays the audio messages and leaves the RawAudio channel).
if fox_check mcap-foxglove "$fox_bag" --expect-gap \
    && mcap_check mcap-foxglove "$fox_bag" --signal xrun --expect-gap --recorder "$work/fox-mcap.json" \
      --ref "$work/fox-mcap-ref.wav"; then
  replay_mcap mcap-foxglove "$fox_bag" "$work/fox-mcap-ref.wav"
fi

# 6. MCAP with a loss inside: sim:pattern, a 1000-frame window, the recorder stopped 0.6 s;
# replayed from the .mcap file itself. A recorder with --foxglove-audio beside it, stopped
# with it.
bass acquire sim:pattern -r 8000 --frames 100 --chunks 10 -c 2 >/dev/null
loss_bag=$work/rec/loss-mcap
fox_loss=$work/rec/fox-loss.mcap
"$bin/bass" record --format mcap "$loss_bag" --frames 12000 -q --json >"$work/loss-mcap.json" &
rec=$!
"$bin/bass" record "$fox_loss" --foxglove-audio --frames 12000 -q &
rec_fox=$!
sleep 0.4
kill -STOP "$rec" "$rec_fox"; sleep 0.6; kill -CONT "$rec" "$rec_fox"
wait "$rec" || true
wait "$rec_fox" || bad "mcap-foxglove-loss: bass record --foxglove-audio failed"
if mcap_check mcap-loss "$loss_bag" --signal pattern --expect-loss --expect-bound --recorder "$work/loss-mcap.json" \
    --ref "$work/loss-mcap-ref.wav"; then
  replay_mcap mcap-loss "$loss_bag/loss-mcap_0.mcap" "$work/loss-mcap-ref.wav"
fi
fox_check mcap-foxglove-loss "$fox_loss" --expect-loss || true

# 7. The replay of an MCAP recording keeps the recorded chunks: another chunk size is refused.
if out=$(bass acquire "sim:file:$gap_bag" -r 8000 --frames 50 --chunks 400 -c 2 2>&1); then
  bad "mcap-refused: a replay with 50-frame chunks of a 100-frame recording was accepted"
elif [[ $out == *"recorded with 100 frames per chunk"* ]]; then
  ok "mcap-refused: the replay with 50-frame chunks is refused: \"...recorded with 100 frames per chunk...\""
else
  bad "mcap-refused: refused, but not for the chunk size: $out"
fi

# xdf_check CASE XDF ARGS...: `bass record --check`, then pyxdf's reading against the WAV.
xdf_check() {
  local case=$1 file=$2; shift 2
  if ! out=$(bass record --check "$file" 2>&1); then
    bad "$case: bass record --check: $out"; return
  fi
  ok "$case: bass record --check: $out"
  if out=$(python3 "$top/tests/replay/xdf_check.py" "$file" "$@" 2>&1); then
    ok "$case: $out"
  else
    bad "$case: $out"
  fi
}

# 8. XDF: the sim:xrun recording made beside gap-ends.
xdf_check xdf-gap "$gap_xdf" --wav "$gap" --recorder "$work/gap-xdf.json" --expect-gap

# 9. XDF with a loss inside: sim:pattern, a 1000-frame window, channels 1 and 0 recorded, the
# XDF recorder stopped 0.6 s; a WAV recorder beside it (from the oldest frame, not stopped)
# holds every frame and row.
bass acquire sim:pattern -r 8000 --frames 100 --chunks 10 -c 2 >/dev/null
loss_wav=$work/rec/loss-beside.wav
loss_xdf=$work/rec/loss.xdf
"$bin/bass" record "$loss_wav" --from oldest --frames 20000 -q &
wrec=$!
"$bin/bass" record "$loss_xdf" --frames 12000 --channels 1,0 -q --json >"$work/loss-xdf.json" &
rec=$!
sleep 0.4
kill -STOP "$rec"; sleep 0.6; kill -CONT "$rec"
wait "$rec" || bad "xdf-loss: bass record FILE.xdf failed"
wait "$wrec" || bad "xdf-loss: the WAV recorder beside it failed"
xdf_check xdf-loss "$loss_xdf" --wav "$loss_wav" --channels 1,0 --recorder "$work/loss-xdf.json" --expect-loss

# 10. XDF after a SIGKILL: the kill between two checkpoints (the size at rest for 200 ms;
# chunks reach the disk once a second); a WAV recorder beside it holds the frames.
bass acquire sim:pattern -r 8000 --frames 100 --chunks 200 -c 2 >/dev/null
kill_wav=$work/rec/kill-beside.wav
kill_xdf=$work/rec/kill.xdf
"$bin/bass" record "$kill_wav" --from oldest --frames 40000 -q &
wrec=$!
"$bin/bass" record "$kill_xdf" -q &
rec=$!
size=0
for _ in $(seq 100); do
  before=$(stat -c %s "$kill_xdf" 2>/dev/null || echo 0); sleep 0.2
  size=$(stat -c %s "$kill_xdf" 2>/dev/null || echo 0)
  (( size > 20000 && size == before )) && break
done
kill -KILL "$rec"; wait "$rec" 2>/dev/null || true
wait "$wrec" || bad "xdf-kill: the WAV recorder beside it failed"
xdf_check xdf-kill "$kill_xdf" --wav "$kill_wav" --killed

summary
