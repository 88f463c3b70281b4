#!/usr/bin/env bash
# Where the network tail comes from: 48-frame chunks stamped at every stage, one-way delays
# exact (the two namespaces share CLOCK_MONOTONIC). Not part of `make bench`: it needs a build
# with stamps.patch applied (`git apply bench/net-stages/stamps.patch`, then make build-all;
# serve puts its put() time as the attachment, the mirror keeps each chunk's header stamps,
# callback and replica-publish times and writes them at exit). The delay readers' DELAY_TRACE
# gives the wake-ups. stages.py joins them per chunk: publish -> serve stamp -> put -> mirror
# callback -> replica published -> reader awake, p50/p99/p99.9, and which stage the worst 1 %
# spent longest in.
# Usage: bench/net-stages/run.sh OUTDIR SECONDS [ZENOH_CONFIG|-] [BUSY_LOOPS]
# Environment: BRT=P bassd at SCHED_FIFO P; CHRT="chrt -f P" serve and mirror under chrt;
# RCHRT="chrt -f P" the readers; ZRT=... ZENOH_RUNTIME. Namespaces removed on exit.
# Who held a CPU when a stage was late: `perf sched record -a -o F -- sleep 8` beside a run, then
# `perf sched timehist -i F -w` around the late chunk (docs/performance.md, part 8).
set -euo pipefail
OUT=$1; SECS=$2; ZC=${3:--}; LOAD=${4:-0}
ROOT=$(cd "$(dirname "$0")/../.." && pwd); BIN=${BENCH_NET_BIN:-${CARGO_TARGET_DIR:-$ROOT/target}/release}
mkdir -p "$OUT"
NS_A=trA$$; NS_B=trB$$; WORK=$(mktemp -d /tmp/bass-trace.XXXXXX); PIDS=()
cleanup() { set +e; for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done; sleep 0.5
  ip netns del "$NS_A" 2>/dev/null; ip netns del "$NS_B" 2>/dev/null; rm -rf "$WORK"; }
trap cleanup EXIT
ip netns add "$NS_A"; ip netns add "$NS_B"
ip link add vA netns "$NS_A" type veth peer name vB netns "$NS_B"
for n in "$NS_A" "$NS_B"; do ip -n "$n" link set lo up; done
ip -n "$NS_A" addr add fd00:ba55::1/64 dev vA nodad; ip -n "$NS_B" addr add fd00:ba55::2/64 dev vB nodad
ip -n "$NS_A" link set vA up; ip -n "$NS_B" link set vB up
IN_A=(ip netns exec "$NS_A" env BASS_RUNTIME_DIR="$WORK/a"); IN_B=(ip netns exec "$NS_B" env BASS_RUNTIME_DIR="$WORK/b")
mkdir -p "$WORK/a" "$WORK/b"
[ -n "${ZRT:-}" ] && export ZENOH_RUNTIME="$ZRT"
EP="tcp/[fd00:ba55::1]:7447"
ZX=(); [ "$ZC" != - ] && ZX=(--zenoh-config "$ZC")
"${IN_A[@]}" "$BIN/bassd" --name src --rt-priority ${BRT:-0} --acquire sim:pattern --rate 48000 --frames 48 --chunks 500 --channels 2 >"$WORK/bassd.log" 2>&1 & PIDS+=($!)
"${IN_A[@]}" BASS_TRACE=1 ${CHRT:-} "$BIN/bass-bridge" serve --insecure --name src --listen "$EP" --no-scouting "${ZX[@]}" >"$OUT/serve.log" 2>&1 & SERVE=$!; PIDS+=($SERVE)
sleep 0.5
"${IN_B[@]}" BASS_TRACE="$OUT/mirror.trace" ${CHRT:-} "$BIN/bass-bridge" mirror --insecure --source src --name rep --connect "$EP" --no-scouting "${ZX[@]}" --status-file "$OUT/status.json" >"$OUT/mirror.log" 2>&1 & MIRROR=$!; PIDS+=($MIRROR)
sleep 3
for i in $(seq "$LOAD"); do timeout $((SECS + 3)) sh -c 'while :; do :; done' & PIDS+=($!); done
uptime > "$OUT/load"
S0=$(awk '{print $14+$15}' /proc/$SERVE/stat); M0=$(awk '{print $14+$15}' /proc/$MIRROR/stat); T0=$(date +%s.%N)
"${IN_A[@]}" DELAY_TRACE="$OUT/local.trace" ${RCHRT:-} "$BIN/examples/delay_reader" src "$SECS" >"$OUT/local.json" & L=$!
"${IN_B[@]}" DELAY_TRACE="$OUT/remote.trace" ${RCHRT:-} "$BIN/examples/delay_reader" rep "$SECS" >"$OUT/remote.json"
wait $L
S1=$(awk '{print $14+$15}' /proc/$SERVE/stat); M1=$(awk '{print $14+$15}' /proc/$MIRROR/stat); T1=$(date +%s.%N)
uptime >> "$OUT/load"
python3 -c "print('serve %.1f %% mirror %.1f %%' % (($S1-$S0)/($T1-$T0), ($M1-$M0)/($T1-$T0)))" > "$OUT/cpu"
kill $MIRROR $SERVE; wait $MIRROR $SERVE 2>/dev/null || true
sleep 0.5
cat "$OUT/local.json" "$OUT/remote.json" "$OUT/cpu" "$OUT/load"
python3 "$ROOT/bench/net-stages/stages.py" "$OUT"
