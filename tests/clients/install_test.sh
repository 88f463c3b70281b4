#!/usr/bin/env bash
# `make install PREFIX=<tmp>`, then builds tests/clients/install/app.c out of tree against the
# installed files with pkg-config and with CMake (shared and static), and runs each build
# against the installed bassd.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
WORK=$(mktemp -d)
PREFIX=$WORK/prefix
BROKER_PID=
cleanup() { [[ -n $BROKER_PID ]] && kill "$BROKER_PID" 2>/dev/null && wait "$BROKER_PID" 2>/dev/null; rm -rf "$WORK"; }
trap cleanup EXIT

make -C "$ROOT" --no-print-directory install PREFIX="$PREFIX" >"$WORK/install.log" 2>&1 || { cat "$WORK/install.log"; exit 1; }
for f in bin/bassd bin/bass lib/libbassclient.so lib/libbassclient.a include/bass.h include/bass.hpp \
         lib/pkgconfig/bassclient.pc lib/cmake/bassclient/bassclientConfig.cmake \
         lib/cmake/bassclient/bassclientConfigVersion.cmake share/bass/matlab/bass_mex.c; do
  [[ -f $PREFIX/$f ]] || { echo "install: $f missing" >&2; exit 1; }
done
echo "install: files in place under $PREFIX"

# Out of tree: a copy of the program, nothing else of the source tree.
mkdir -p "$WORK/src" && cp "$ROOT/tests/clients/install/app.c" "$ROOT/tests/clients/install/CMakeLists.txt" "$WORK/src/"
export PKG_CONFIG_PATH=$PREFIX/lib/pkgconfig
echo "install: pkg-config --cflags --libs bassclient = $(pkg-config --cflags --libs bassclient)"
# shellcheck disable=SC2046
cc -std=c11 -Wall -Wextra -Wpedantic -Werror $(pkg-config --cflags bassclient) "$WORK/src/app.c" \
   $(pkg-config --libs bassclient) -Wl,-rpath,"$PREFIX/lib" -o "$WORK/app_pkgconfig"
cmake -S "$WORK/src" -B "$WORK/build" -DCMAKE_PREFIX_PATH="$PREFIX" >"$WORK/cmake.log" 2>&1 \
  || { cat "$WORK/cmake.log"; exit 1; }
cmake --build "$WORK/build" >"$WORK/build.log" 2>&1 || { cat "$WORK/build.log"; exit 1; }
if ldd "$WORK/build/app_static" | grep -q libbassclient; then
  echo "install: app_static links libbassclient.so" >&2; exit 1
fi

# A live broker from the installed files.
export BASS_RUNTIME_DIR=$WORK/run
mkdir -p "$BASS_RUNTIME_DIR"
"$PREFIX/bin/bassd" --name inst 2>"$WORK/bassd.log" &
BROKER_PID=$!
for _ in $(seq 100); do [[ -S $BASS_RUNTIME_DIR/bass-inst.sock ]] && break; sleep 0.05; done
for app in "$WORK/app_pkgconfig" "$WORK/build/app_shared" "$WORK/build/app_static"; do
  echo "install: $(basename "$app"): $("$app" inst)"
done
"$PREFIX/bin/bass" --name inst status >/dev/null
echo "install: ok"
