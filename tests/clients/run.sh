#!/usr/bin/env bash
# The client suite (make test-clients): builds the C/C++ clients and the MEX gateway, runs the
# Python package tests, the cross-language conformance suite, the BASC seed examples against a
# live port (bassd sim:pattern, else examples-c/sim_writer), the Octave tests and the
# installation test.
set -euo pipefail
SUITE=tests/clients
source "$(dirname "$0")/../lib.sh"
ROOT=$TOP
export CLIENTS_BIN=${CLIENTS_BIN:-$TARGET/clients}
cd "$ROOT"

# pytest ARGS..., reporting skips (-rs); with BASS_TESTS_NO_SKIP=1 (CI as root, every tool
# installed: .ci/run) a skipped test fails the suite.
pytest_no_skip() {
  local log rc=0
  log=$(mktemp)
  python3 -m pytest -rs "$@" 2>&1 | tee "$log" || rc=$?
  if ((rc == 0)) && [[ "${BASS_TESTS_NO_SKIP:-0}" != 0 ]] && grep -q '^SKIPPED' "$log"; then
    echo "tests/clients: tests were skipped but BASS_TESTS_NO_SKIP is set: in CI a skip is a failure" >&2
    rc=1
  fi
  rm -f "$log"
  return "$rc"
}

echo "== build C/C++ clients, conformance drivers, MEX"
tests/clients/build.sh
if command -v mkoctfile >/dev/null; then matlab/build_octave.sh "$CLIENTS_BIN/matlab"; fi

echo "== python package"
pytest_no_skip -q python/tests

echo "== conformance"
tests/conformance/run.sh

echo "== BASC seed examples, wait mode, Octave"
pytest_no_skip -q -s -p no:cacheprovider tests/clients

if [[ -x tests/clients/install_test.sh ]]; then
  echo "== make install + out-of-tree build"
  tests/clients/install_test.sh
fi
echo "test-clients: all passed"
