#!/usr/bin/env bash
# The client suite (make test-clients): builds the C/C++ clients and the MEX gateway, runs the
# Python package tests, the cross-language conformance suite, the BASC seed examples against a
# live port (bassd sim:pattern, else examples-c/sim_writer), the Octave tests and the
# installation test.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
export CLIENTS_BIN=${CLIENTS_BIN:-$TARGET/clients}
cd "$ROOT"

echo "== build C/C++ clients, conformance drivers, MEX"
tests/clients/build.sh
if command -v mkoctfile >/dev/null; then matlab/build_octave.sh "$CLIENTS_BIN/matlab"; fi

echo "== python package"
python3 -m pytest -q python/tests

echo "== conformance"
tests/conformance/run.sh

echo "== BASC seed examples, wait mode, Octave"
python3 -m pytest -q -s -p no:cacheprovider tests/clients

if [[ -x tests/clients/install_test.sh ]]; then
  echo "== make install + out-of-tree build"
  tests/clients/install_test.sh
fi
echo "test-clients: all passed"
