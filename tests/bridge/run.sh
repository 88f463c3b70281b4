#!/usr/bin/env bash
# The network suite (make test-bridge): every tests/bridge/cases/*.sh, each a process with its
# own network namespaces (tests/bridge/lib.sh). The long cases (link outages of 20 s and 60 s)
# run beside the others, so the suite takes about as long as its longest case; a case's
# transcript is printed when it ends. Fails if any case fails.
#
#   tests/bridge/run.sh              all cases
#   tests/bridge/run.sh basic rogue  only these
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
cd "$ROOT"
if [[ $(id -u) -ne 0 ]]; then echo "test-bridge: needs root (network namespaces)"; exit 1; fi
# Exactly make test-rust's build (same feature unification), so nothing is rebuilt after it.
make -C "$ROOT" --no-print-directory build-all || exit 1

# iceoryx2 keeps a small per-machine management file (/dev/shm/iox2_*global_mgmt) after its
# last node exits, by design; the ones this suite created are removed at the end, the ones
# that were there before (another iceoryx2 user's) are left alone.
IOX_BEFORE=$(ls /dev/shm 2>/dev/null | grep '^iox2_' || true)
LOGS=$(mktemp -d /tmp/bass-bridge-suite.XXXXXX)
cleanup() {
  for f in $(ls /dev/shm 2>/dev/null | grep '^iox2_'); do
    grep -qxF "$f" <<<"$IOX_BEFORE" || rm -f "/dev/shm/$f"
  done
  rm -rf "$LOGS"
}
trap cleanup EXIT

if (($#)); then CASES=("$@"); else
  CASES=(); for f in tests/bridge/cases/*.sh; do CASES+=("$(basename "${f%.sh}")"); done
fi
# Long cases first, in the background; the rest one after another beside them (2 cores).
LONG=(); SHORT=()
for c in "${CASES[@]}"; do
  if [[ $c == outage-long* ]]; then LONG+=("$c"); else SHORT+=("$c"); fi
done
declare -A PID
for c in "${LONG[@]}"; do
  bash "tests/bridge/cases/$c.sh" >"$LOGS/$c.log" 2>&1 & PID[$c]=$!
done
FAILED=()
for c in "${SHORT[@]}"; do
  echo "=== $c"
  if bash "tests/bridge/cases/$c.sh" 2>&1 | tee "$LOGS/$c.log"; then :; else FAILED+=("$c"); fi
done
for c in "${LONG[@]}"; do
  wait "${PID[$c]}"; rc=$?
  echo "=== $c (ran beside the others)"; cat "$LOGS/$c.log"
  ((rc == 0)) || FAILED+=("$c")
done
if ((${#FAILED[@]})); then echo "test-bridge: failed cases: ${FAILED[*]}"; exit 1; fi
echo "test-bridge: all ${#CASES[@]} cases passed"
