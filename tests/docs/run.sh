#!/usr/bin/env bash
# The docs test (make test-docs): the README's commands, the tutorial's shell, Python and Octave
# snippets and docs/clients.md's Python run as written against real brokers on simulated
# devices, each document in a temporary runtime directory (tests/docs/run_docs.py says how a
# block runs and how docs mark one that cannot run here). The C program of the README is
# compiled and run by tests/clients/install_test.sh.
#   BASS_BIN_DIR  where bassd, bass and libbassclient.so(.0) are (default <target>/release)
set -euo pipefail
SUITE=tests/docs
source "$(dirname "$0")/../lib.sh"
ROOT=$TOP
need_built bassd bass libbassclient.so libbassclient.so.0
BIN=$(cd "$BIN" && pwd)
MEXDIR=$TARGET/docs-test/matlab
opts=()
if command -v octave >/dev/null && command -v mkoctfile >/dev/null; then
  BASS_LIBDIR=$BIN "$ROOT/matlab/build_octave.sh" "$MEXDIR"
elif [[ "${BASS_TESTS_NO_SKIP:-0}" != 0 ]]; then
  echo "tests/docs: Octave (octave, mkoctfile) is missing but BASS_TESTS_NO_SKIP is set: in CI a skip is a failure" >&2
  exit 1
else
  echo "tests/docs: Octave is not installed: its blocks are skipped (make deps installs it)"
  opts+=(--no-octave)
fi
run_docs() { python3 "$ROOT/tests/docs/run_docs.py" --bin "$BIN" --mexdir "$MEXDIR" "${opts[@]}" "$@"; }

# The runner first, on documents made to fail (tests/docs/selftest/bad-*.md) and one made to pass.
if (($# == 0)); then
  echo "== the runner fails what it must (tests/docs/selftest)"
  log=$(mktemp)
  trap 'rm -f "$log"' EXIT
  for f in "$ROOT"/tests/docs/selftest/bad-*.md; do
    [[ ${opts[*]-} == *--no-octave* && $f == *octave* || ${opts[*]-} == *--no-octave* && $f == *flood* ]] && continue
    if run_docs "$f::broker" >"$log" 2>&1 || ! grep -q '^FAIL' "$log"; then
      cat "$log"; echo "tests/docs: the runner passed ${f#"$ROOT"/}, which must fail" >&2; exit 1
    fi
    # ... and for the reason the document gives (<!-- selftest-expect: REGEX --> lines), not another
    expects=$(sed -n 's/^<!-- selftest-expect: \(.*\) -->$/\1/p' "$f")
    [[ -n $expects ]] || { echo "tests/docs: ${f#"$ROOT"/} has no selftest-expect line" >&2; exit 1; }
    while IFS= read -r e; do
      grep -Eq -- "$e" "$log" || {
        cat "$log"; echo "tests/docs: ${f#"$ROOT"/} failed, but its log does not match: $e" >&2; exit 1; }
    done <<<"$expects"
    echo "ok   ${f#"$ROOT"/} fails: $(grep -m1 '^FAIL' "$log" | cut -c1-110)"
  done
  run_docs "$ROOT/tests/docs/selftest/good.md::broker" >"$log" 2>&1 || { cat "$log"; exit 1; }
  grep -q '^skip .*would fail' "$log" || { cat "$log"; echo "tests/docs: the skip marker was not honoured" >&2; exit 1; }
  grep -q '^ok .*(python): .*output as shown' "$log" || { cat "$log"; echo "tests/docs: a python block's output was not compared" >&2; exit 1; }
  echo "ok   tests/docs/selftest/good.md passes"
  echo "== the documentation"
fi
run_docs "$@"
