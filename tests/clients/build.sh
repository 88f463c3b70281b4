#!/usr/bin/env bash
# Builds the C and C++ clients, examples and conformance drivers against include/bass.h and the
# release libbassclient, with -Wall -Wextra -Wpedantic -Werror (and ASan/UBSan for the drivers).
# Prints nothing but errors; the binaries go to $CLIENTS_BIN (default <target>/clients).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
LIBDIR=$TARGET/release
BIN=${CLIENTS_BIN:-$TARGET/clients}
mkdir -p "$BIN"
[[ -f $LIBDIR/libbassclient.so ]] || { echo "build.sh: $LIBDIR/libbassclient.so missing (cargo build --release)" >&2; exit 1; }

CC=${CC:-cc}
CXX=${CXX:-c++}
WARN=(-Wall -Wextra -Wpedantic -Werror)
LINK=(-L"$LIBDIR" -lbassclient -Wl,-rpath,"$LIBDIR")
SAN=()
# ASan/UBSan where the toolchain has them (the conformance drivers and the C++ example).
if echo 'int main(void){return 0;}' | $CC -x c -fsanitize=address,undefined -o /dev/null - 2>/dev/null; then
  SAN=(-fsanitize=address,undefined -fno-omit-frame-pointer)
fi

$CC -std=c11 "${WARN[@]}" -O2 -I"$ROOT/include" "$ROOT/examples-c/basc.c" -o "$BIN/basc" "${LINK[@]}"
$CC -std=c11 "${WARN[@]}" -O1 -g "${SAN[@]}" -I"$ROOT/include" "$ROOT/examples-c/basc.c" -o "$BIN/basc_san" "${LINK[@]}"
$CC -std=c11 "${WARN[@]}" -O2 -I"$ROOT/include" "$ROOT/examples-c/sim_writer.c" -o "$BIN/sim_writer" "${LINK[@]}"
$CC -std=c11 "${WARN[@]}" -g "${SAN[@]}" -I"$ROOT/include" "$ROOT/tests/conformance/driver_c.c" -o "$BIN/driver_c" "${LINK[@]}"
if [[ -f $ROOT/include/bass.hpp ]]; then
  $CXX -std=c++17 "${WARN[@]}" -g "${SAN[@]}" -I"$ROOT/include" \
    "$ROOT/tests/conformance/driver_cpp.cpp" -o "$BIN/driver_cpp" "${LINK[@]}"
  $CXX -std=c++17 "${WARN[@]}" -O2 -I"$ROOT/include" \
    "$ROOT/examples-c/blocks.cpp" -o "$BIN/blocks_cpp" "${LINK[@]}"
fi
