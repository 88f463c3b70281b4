#!/usr/bin/env bash
# Builds the MEX gateway for GNU Octave: matlab/build_octave.sh [OUTDIR]
# (default OUTDIR: <target>/clients/matlab; the .m files are copied next to the .mex).
# For Matlab, see matlab/README.md (`mex` with the same sources and flags).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
LIBDIR=${BASS_LIBDIR:-$TARGET/release}
OUT=${1:-$TARGET/clients/matlab}
mkdir -p "$OUT"
CFLAGS="-std=c11 -Wall -Wextra -Wpedantic -Werror -fPIC -O2" \
  mkoctfile --mex -I"$ROOT/include" -L"$LIBDIR" -lbassclient -Wl,-rpath,"$LIBDIR" \
  "$ROOT/matlab/bass_mex.c" -o "$OUT/bass_mex.mex"
rm -f "$OUT"/bass_mex.o
cp "$ROOT"/matlab/*.m "$OUT"/
