#!/usr/bin/env bash
# Cross-language conformance: the vectors generated from the literal seed model are replayed
# through the writer and reader C ABI by drivers in Rust, C, C++, Python and Octave (MEX);
# every driver's output must equal vectors.txt byte for byte.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
SUITE=tests/conformance
source "$HERE/../lib.sh"
ROOT=$TOP
# The drivers tests/clients/build.sh built.
BIN=${CLIENTS_BIN:-$TARGET/clients}
VEC=$HERE/vectors.txt
OUT=$(mktemp -d)
export BASS_RUNTIME_DIR=$OUT/run
mkdir -p "$BASS_RUNTIME_DIR"
trap 'rm -rf "$OUT"' EXIT

# The committed vectors are what the model generates now.
python3 "$HERE/gen_vectors.py" "$OUT/regenerated.txt"
cmp -s "$VEC" "$OUT/regenerated.txt" || { echo "conformance: vectors.txt is stale: run tests/conformance/gen_vectors.py" >&2; exit 1; }
echo "conformance: $(grep -c '^case ' "$VEC") cases, $(grep -c '^publish ' "$VEC") publishes, $(grep -c '^read ' "$VEC") stereo reads, $(grep -c '^readm ' "$VEC") multi-channel reads"

[[ -x $BIN/driver_c ]] || "$ROOT/tests/clients/build.sh"
fail=0
check() {  # check NAME OUTPUT
  if cmp -s "$VEC" "$2"; then
    echo "conformance: $1 agrees bit for bit"
  else
    echo "conformance: $1 DIFFERS:" >&2
    diff "$VEC" "$2" | head -5 | cut -c1-160 >&2
    fail=1
  fi
}

"$BIN/driver_c" "$VEC" > "$OUT/c.txt"; check C "$OUT/c.txt"
"$BIN/driver_cpp" "$VEC" > "$OUT/cpp.txt"; check C++ "$OUT/cpp.txt"
python3 "$HERE/driver_py.py" "$VEC" > "$OUT/py.txt"; check Python "$OUT/py.txt"
(cd "$ROOT" && BASS_CONFORMANCE_OUT="$OUT/rust.txt" cargo test -q --release -p bassclient --test conformance >/dev/null 2>"$OUT/rust.log") \
  || { cat "$OUT/rust.log" >&2; fail=1; }
check Rust "$OUT/rust.txt"
if command -v octave >/dev/null; then
  MEXDIR=$BIN/matlab
  [[ -f $MEXDIR/bass_mex.mex ]] || "$ROOT/matlab/build_octave.sh" "$MEXDIR"
  octave --no-gui --norc -q --path "$MEXDIR" --path "$HERE" \
    --eval "driver_octave('$VEC', '$OUT/octave.txt')" 2> >(grep -v 'ignoring const execution_exception' >&2)
  check Octave "$OUT/octave.txt"
else
  echo "conformance: octave not installed (scripts/install-deps.sh --with-octave)" >&2
  fail=1
fi
exit $fail
