#!/usr/bin/env bash
# Runs the bass benchmark harness and regenerates docs/performance.md and docs/perf-*.png.
# Called by `make bench` (after `make build`); not part of `make test`.
# Usage: scripts/bench.sh [bass-bench options, e.g. --quick or --parts 1,3]
set -euo pipefail
cd "$(dirname "$0")/.."
# Part 7 compares bass with PipeWire: its daemon and libpipewire (skipped, and said so, without).
scripts/install-deps.sh --with-bench
target="${CARGO_TARGET_DIR:-target}"
# The one feature set of the workspace (the network parts build the same: nothing twice).
make --no-print-directory build-all
"$target/release/bass-bench" --docs docs "$@"
# The network part (bass-bridge between two network namespaces; needs root).
if [[ $(id -u) -eq 0 ]]; then
  scripts/bench-network.sh
  # The ROS 2 topic's delay and CPU against the replica's, same run (bench/ros2-results.md).
  scripts/bench-ros2.sh
else
  echo "bench: network parts skipped (need root)"
fi
