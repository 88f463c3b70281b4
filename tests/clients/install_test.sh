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
VERSION=$(sed -n 's/^version = "\(.*\)"/\1/p' "$ROOT/Cargo.toml" | head -1)
for f in bin/bassd bin/bass "lib/libbassclient.so.$VERSION" lib/libbassclient.a include/bass.h include/bass.hpp \
         lib/pkgconfig/bassclient.pc lib/cmake/bassclient/bassclientConfig.cmake \
         lib/cmake/bassclient/bassclientConfigVersion.cmake share/bass/matlab/bass_mex.c share/bass/matlab/bass_mex_tables.h share/bass/matlab/bass_mex_results.h share/bass/matlab/bass_mex_fields.h; do
  [[ -f $PREFIX/$f ]] || { echo "install: $f missing" >&2; exit 1; }
done
echo "install: files in place under $PREFIX"
# The SONAME and the usual symlinks: .so -> .so.0 -> .so.VERSION.
[[ $(readlink "$PREFIX/lib/libbassclient.so") == libbassclient.so.0 ]] || { echo "install: libbassclient.so link" >&2; exit 1; }
[[ $(readlink "$PREFIX/lib/libbassclient.so.0") == "libbassclient.so.$VERSION" ]] || { echo "install: libbassclient.so.0 link" >&2; exit 1; }
readelf -d "$PREFIX/lib/libbassclient.so.$VERSION" | grep -q 'SONAME.*\[libbassclient\.so\.0\]' \
  || { echo "install: SONAME is not libbassclient.so.0" >&2; exit 1; }
echo "install: SONAME libbassclient.so.0, links in place"

# Out of tree: a copy of the program, nothing else of the source tree.
mkdir -p "$WORK/src" && cp "$ROOT/tests/clients/install/app.c" "$ROOT/tests/clients/install/CMakeLists.txt" "$WORK/src/"
export PKG_CONFIG_PATH=$PREFIX/lib/pkgconfig
echo "install: pkg-config --cflags --libs bassclient = $(pkg-config --cflags --libs bassclient)"
# shellcheck disable=SC2046
cc -std=c11 -Wall -Wextra -Wpedantic -Werror $(pkg-config --cflags bassclient) "$WORK/src/app.c" \
   $(pkg-config --libs bassclient) -Wl,-rpath,"$PREFIX/lib" -o "$WORK/app_pkgconfig"
readelf -d "$WORK/app_pkgconfig" | grep -q 'NEEDED.*\[libbassclient\.so\.0\]' \
  || { echo "install: app does not record libbassclient.so.0" >&2; exit 1; }
# The README's C program, extracted and compiled exactly with its own compile line (plus the
# strict warnings), out of tree.
awk '/readme-c-begin/{on=1; next} on && /^```c/{inblk=1; next} inblk && /^```/{exit} inblk{print}' \
  "$ROOT/README.md" > "$WORK/src/prog.c"
[[ -s $WORK/src/prog.c ]] || { echo "install: no C program in README.md" >&2; exit 1; }
# shellcheck disable=SC2046
(cd "$WORK/src" && cc -std=c11 -Wall -Wextra -Wpedantic -Werror prog.c $(pkg-config --cflags --libs bassclient) -o prog)
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
# The README program reads broker "default": run one, start the pattern, run the program.
"$PREFIX/bin/bassd" 2>"$WORK/bassd-default.log" &
BROKER2_PID=$!
for _ in $(seq 100); do [[ -S $BASS_RUNTIME_DIR/bass-default.sock ]] && break; sleep 0.05; done
"$PREFIX/bin/bass" acquire sim:pattern --rate 48000 --frames 480 --chunks 100 >/dev/null
out=$(LD_LIBRARY_PATH="$PREFIX/lib" "$WORK/src/prog")
kill "$BROKER2_PID"; wait "$BROKER2_PID" 2>/dev/null || true
[[ $out == "12000 frames, 0 lost, next frame 12001" ]] || { echo "install: README program printed: $out" >&2; exit 1; }
echo "install: README program: $out"

# pip install ./python (a copy: pip builds in the tree) into a virtual environment, then the
# package finds the installed library through the dynamic loader, outside the source tree.
cp -r "$ROOT/python" "$WORK/pysrc"
python3 -m venv --system-site-packages "$WORK/venv"
"$WORK/venv/bin/pip" install -q --no-deps "$WORK/pysrc" >"$WORK/pip.log" 2>&1 \
  || { cat "$WORK/pip.log"; exit 1; }
pyout=$(cd "$WORK" && env -u BASS_LIB -u CARGO_TARGET_DIR LD_LIBRARY_PATH="$PREFIX/lib" "$WORK/venv/bin/python" -c \
  'import bass, bass._lib as l; print(bass.__file__.startswith("'"$WORK"'/venv"), l.lib._name)')
[[ $pyout == "True "*libbassclient* ]] || { echo "install: pip-installed bass: $pyout" >&2; exit 1; }
echo "install: pip install ./python: $pyout"
# Without LD_LIBRARY_PATH the loader does not search $PREFIX/lib: the package falls back to the
# libdir pkg-config gives (PKG_CONFIG_PATH is set above).
pyout=$(cd "$WORK" && env -u BASS_LIB -u LD_LIBRARY_PATH -u CARGO_TARGET_DIR "$WORK/venv/bin/python" -c \
  'import bass._lib as l; print(l.lib._name)')
[[ $pyout == "$PREFIX/lib/libbassclient.so" ]] || { echo "install: pkg-config fallback: $pyout" >&2; exit 1; }
echo "install: library found through pkg-config: $pyout"
echo "install: ok"
