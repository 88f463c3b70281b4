#!/usr/bin/env bash
# make demo: runs bassd on a simulated device (no sound card needed) and a client that prints
# one line per block (frames, loss, level per channel) for a few seconds, or until Ctrl-C.
# Usage: scripts/demo.sh [SECONDS]   (default 5; BASS_DEMO_DEVICE=sim:pattern etc. to change)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN="${CARGO_TARGET_DIR:-target}/release"
SECONDS_TO_RUN="${1:-5}"
DEVICE="${BASS_DEMO_DEVICE:-sim:sine}"
for b in bassd bass; do
  [[ -x "$BIN/$b" ]] || { echo "demo: $BIN/$b missing; run 'cargo build --release --workspace' (or 'make demo')" >&2; exit 1; }
done

export BASS_RUNTIME_DIR
BASS_RUNTIME_DIR="$(mktemp -d -t bass-demo.XXXXXX)"
bassd_pid=""
cleanup() {
  if [[ -n "$bassd_pid" ]] && kill -0 "$bassd_pid" 2>/dev/null; then
    kill -TERM "$bassd_pid" 2>/dev/null || true
    wait "$bassd_pid" 2>/dev/null || true
  fi
  rm -rf "$BASS_RUNTIME_DIR"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

echo "demo: bassd on $DEVICE (44100 Hz, 2205 frames/chunk, 20 chunks) in $BASS_RUNTIME_DIR"
BASS_LOG="${BASS_LOG:-warn}" "$BIN/bassd" &
bassd_pid=$!
# Wait for the control socket instead of sleeping a fixed time.
for _ in $(seq 100); do
  [[ -S "$BASS_RUNTIME_DIR/bass-default.sock" ]] && break
  kill -0 "$bassd_pid" 2>/dev/null || { echo "demo: bassd exited" >&2; exit 1; }
  sleep 0.05
done
"$BIN/bass" devices | sed -n '1,4p'
"$BIN/bass" acquire "$DEVICE" --rate 44100 --frames 2205 --chunks 20
echo "demo: reading blocks of 4410 frames (100 ms) for ${SECONDS_TO_RUN} s; Ctrl-C to stop"
"$BIN/bass" blocks --block 4410 --seconds "$SECONDS_TO_RUN"
"$BIN/bass" status
"$BIN/bass" stop
echo "demo: done"
