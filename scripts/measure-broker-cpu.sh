#!/usr/bin/env bash
# Measures bassd on simulated devices (numbers reported in docs/broker.md):
#  - CPU of bassd (% of one core: the on-CPU time of all its threads from
#    /proc/PID/task/*/schedstat, in ns) over SECONDS seconds, idle (no acquisition: a sleeping
#    broker), at 48 kHz stereo with 64- and 256-frame chunks and with the seed's defaults
#    (44.1 kHz, 2205 x 20);
#  - the time from an Acquire request to the first published chunk (client side: request
#    sent -> frame nFramesPerChunk visible in the port), from a stopped broker, N times;
#  - the rate estimate's error against the simulated device's nominal rate.
# Usage: scripts/measure-broker-cpu.sh [SECONDS (default 10)] [N (default 20)]
# CPU_ONLY=1: only the CPU lines. BASSD_ARGS: extra bassd options, e.g. BASSD_ARGS="--rt-priority 0" for a capture thread
# without real-time scheduling.
set -euo pipefail
top=$(cd "$(dirname "$0")/.." && pwd)
bin="${CARGO_TARGET_DIR:-$top/target}/release"
secs=${1:-10}
n=${2:-20}
export BASS_RUNTIME_DIR
BASS_RUNTIME_DIR=$(mktemp -d -t bass-measure.XXXXXX)
pid=""
cleanup() { [[ -n "$pid" ]] && kill -TERM "$pid" 2>/dev/null; wait 2>/dev/null; rm -rf "$BASS_RUNTIME_DIR"; }
trap cleanup EXIT
# shellcheck disable=SC2086 # BASSD_ARGS is a list of words
BASS_LOG=warn "$bin/bassd" ${BASSD_ARGS:-} 2>"$BASS_RUNTIME_DIR/bassd.log" &
pid=$!
for _ in $(seq 200); do [[ -S "$BASS_RUNTIME_DIR/bass-default.sock" ]] && break; sleep 0.025; done
# On-CPU ns of all of bassd's threads (schedstat's first field; finer than the clock ticks of stat).
cpu_ns() { cat /proc/"$pid"/task/*/schedstat 2>/dev/null | awk '{ s += $1 } END { printf "%.0f", s }'; }
echo "machine: $(nproc) cores, $(uname -r); bassd pid $pid; $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
grep -q "real-time scheduling" "$BASS_RUNTIME_DIR/bassd.log" && echo "note: real-time scheduling refused" || echo "capture thread: SCHED_FIFO (or not requested)"

sample() {  # what
  local t0 c0 t1 c1
  t0=$(date +%s.%N); c0=$(cpu_ns)
  sleep "$secs"
  t1=$(date +%s.%N); c1=$(cpu_ns)
  awk -v c0="$c0" -v c1="$c1" -v t0="$t0" -v t1="$t1" -v what="$1" \
    'BEGIN { printf "cpu  %-40s %6.3f %% of one core (%.1f ms in %.1f s)\n", what, 100 * (c1 - c0) / 1e9 / (t1 - t0), (c1 - c0) / 1e6, t1 - t0 }'
}
cpu() {  # device rate frames chunks
  "$bin/bass" acquire "$1" --rate "$2" --frames "$3" --chunks "$4" >/dev/null
  sleep 1
  sample "$1 $2 Hz, $3 frames x $4 chunks"
}
sleep 1
sample "idle (no acquisition)"
cpu sim:sine 48000 64 750
cpu sim:pattern 48000 256 188
cpu sim:sine 44100 2205 20
cpu sim:pattern 48000 64 750
"$bin/bass" stop >/dev/null
sleep 1
sample "idle again (after Stop)"
# CPU_ONLY=1: the CPU lines only.
[[ -n "${CPU_ONLY:-}" ]] && exit 0

latency() {  # rate frames chunks
  local samples=()
  for _ in $(seq "$n"); do
    "$bin/bass" stop >/dev/null
    local out
    out=$("$bin/bass" acquire sim:pattern --rate "$1" --frames "$2" --chunks "$3" --wait)
    samples+=("$(sed -n 's/.*first chunk published \([0-9.]*\) ms.*/\1/p' <<<"$out")")
  done
  printf '%s\n' "${samples[@]}" | sort -n | awk -v what="$1 Hz, $2 frames/chunk (chunk = $(awk -v f="$2" -v r="$1" 'BEGIN{printf "%.2f", 1000*f/r}') ms)" \
    '{ v[NR] = $1 } END { printf "acquire->first chunk  %-38s median %.2f ms, min %.2f, max %.2f (n=%d)\n", what, v[int((NR+1)/2)], v[1], v[NR], NR }'
}
latency 48000 64 750
latency 44100 2205 20

rate() {  # rate frames chunks
  "$bin/bass" acquire sim:silence --rate "$1" --frames "$2" --chunks "$3" >/dev/null
  local worst=0 last=0
  for s in $(seq "$secs"); do
    sleep 1
    local est
    est=$("$bin/bass" status | sed -n 's/^rate est\. *\([0-9.]*\) Hz/\1/p')
    if ((s > secs / 2)); then
      worst=$(awk -v a="$worst" -v e="$est" -v r="$1" 'BEGIN { d = (e / r - 1) * 1e6; if (d < 0) d = -d; print (d > a ? d : a) }')
    fi
    last=$est
  done
  awk -v e="$last" -v r="$1" -v w="$worst" -v what="$1 Hz, $2 frames/chunk" -v s="$secs" \
    'BEGIN { printf "rate estimate  %-30s after %d s: %.3f Hz (%+.1f ppm); worst over the last half: %.1f ppm\n", what, s, e, (e / r - 1) * 1e6, w }'
}
rate 48000 64 750
rate 44100 2205 20
