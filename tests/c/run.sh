#!/usr/bin/env bash
# Builds the C ABI test against include/bass.h and the cdylib with strict warnings, then runs
# it plain, under AddressSanitizer + UndefinedBehaviorSanitizer, and under valgrind's memcheck
# (with the C examples: a C or C++ program run under memcheck must run clean).
set -euo pipefail
SUITE=tests/c
source "$(dirname "$0")/../lib.sh"
top=$TOP lib=$BIN
need_built libbassclient.so
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
cc=${CC:-cc}
flags=(-std=c11 -Wall -Wextra -Wpedantic -Werror -I "$top/include")
link=(-L "$lib" -lbassclient -Wl,-rpath,"$lib" -lpthread)

# -g on the plain builds: memcheck (below) runs them, and names lines in what it reports.
"$cc" "${flags[@]}" -O2 -g "$top/tests/c/abi_test.c" -o "$out/abi_test" "${link[@]}"
"$cc" "${flags[@]}" -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all \
  "$top/tests/c/abi_test.c" -o "$out/abi_test_asan" "${link[@]}"
# The callback stream (bass_stream_*), plain and sanitized.
"$cc" "${flags[@]}" -O2 -g "$top/tests/c/stream_test.c" -o "$out/stream_test" "${link[@]}"
"$cc" "${flags[@]}" -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all \
  "$top/tests/c/stream_test.c" -o "$out/stream_test_asan" "${link[@]}"
# The C stream's steady path makes no allocation (interposes malloc: no sanitizer build).
"$cc" "${flags[@]}" -O2 "$top/tests/c/stream_rt.c" -o "$out/stream_rt" "${link[@]}"
# The C++ wrapper's callback stream (include/bass.hpp), plain and sanitized.
cxxflags=(-std=c++17 -Wall -Wextra -Wpedantic -Werror -I "$top/include")
"${CXX:-c++}" "${cxxflags[@]}" -O2 -g "$top/tests/c/stream_test.cpp" -o "$out/stream_test_cpp" "${link[@]}"
"${CXX:-c++}" "${cxxflags[@]}" -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all \
  "$top/tests/c/stream_test.cpp" -o "$out/stream_test_cpp_asan" "${link[@]}"
# The header must also compile as C++.
printf '#include "bass.h"\nint main() { return bass_version() == nullptr; }\n' > "$out/hpp.cpp"
"${CXX:-c++}" -std=c++17 -Wall -Wextra -Wpedantic -Werror -I "$top/include" "$out/hpp.cpp" -o "$out/hpp" "${link[@]}"

# bass_port_get_info asks /proc once per writer, not once per call (strace counts the opens).
"$cc" "${flags[@]}" -O2 -g "$top/tests/c/info_liveness.c" -o "$out/info_liveness" "${link[@]}"
mkdir -p "$out/rt-info"
echo "== info_liveness (under strace)"
BASS_RUNTIME_DIR="$out/rt-info" strace -f -qq -e trace=openat -o "$out/info.strace" "$out/info_liveness"
stats=$(grep -c '"/proc/[0-9]*/stat"' "$out/info.strace" || true)
echo "info_liveness: $stats opens of /proc/PID/stat for 2000 calls"
((stats <= 2)) || { echo "tests/c: bass_port_get_info reads /proc on every call ($stats opens)" >&2; exit 1; }

for t in abi_test abi_test_asan stream_test stream_test_asan stream_test_cpp stream_test_cpp_asan stream_rt; do
  mkdir -p "$out/rt-$t"
  echo "== $t"
  BASS_RUNTIME_DIR="$out/rt-$t" ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 "$out/$t"
done
"$out/hpp"

# Memcheck (valgrind): any error, or a definitely lost block, fails the suite. Before rustix
# read the auxv through glibc (use-libc-auxv, libbassclient/Cargo.toml), every program here
# died at its first clock read. Not stream_rt: it counts allocations by replacing malloc,
# which memcheck replaces too (as ASan does). Valgrind runs threads one at a time: the streams
# lose more frames, counted exactly, as their checks allow. Valgrind 3.19 (Debian 12) does not know pidfd_open (syscall 434) and
# warns: the library then asks /proc. Each run takes a second or two; timeout bounds a hang.
command -v valgrind >/dev/null || { echo "tests/c: valgrind missing (scripts/install-deps.sh)" >&2; exit 1; }
memcheck() { # PROGRAM ARGS...
  timeout -k 5 300 valgrind -q --error-exitcode=97 --leak-check=full --errors-for-leak-kinds=definite \
    --suppressions="$top/tests/c/valgrind.supp" "$@" ||
    { echo "tests/c: memcheck: ${1##*/} failed (exit $?; 97: memcheck errors, above)" >&2; exit 1; }
}
vg_start=$SECONDS
for t in abi_test stream_test stream_test_cpp info_liveness; do
  mkdir -p "$out/vg-$t"
  echo "== $t (valgrind memcheck)"
  BASS_RUNTIME_DIR="$out/vg-$t" memcheck "$out/$t"
done
# The examples, against a port of examples-c/sim_writer (run plain, paced: 100 chunks a second).
for e in sim_writer basc callback; do
  "$cc" "${flags[@]}" -O1 -g "$top/examples-c/$e.c" -o "$out/$e" "${link[@]}"
done
"${CXX:-c++}" "${cxxflags[@]}" -O1 -g "$top/examples-c/blocks.cpp" -o "$out/blocks" "${link[@]}"
export BASS_RUNTIME_DIR="$out/vg-examples"
mkdir -p "$BASS_RUNTIME_DIR"
echo "== examples-c (valgrind memcheck)"
memcheck "$out/sim_writer" --name fast --fast --rate 48000 --fpc 480 --chunks 500
"$out/sim_writer" --name paced --rate 48000 --fpc 480 --cop 50 &
sim=$!
trap '{ kill "$sim"; wait "$sim"; } 2>/dev/null || true; rm -rf "$out"' EXIT
for _ in $(seq 100); do [[ -e "$BASS_RUNTIME_DIR/bass-paced.port" ]] && break; sleep 0.05; done
sleep 0.2 # the header is published right after the file appears
memcheck "$out/basc" --port paced --wait --check-pattern 3 4800 0
memcheck "$out/basc" --port paced --period-ms 50 --check-pattern 2 4800 -4800
memcheck "$out/basc" --port paced --callback --check-pattern 3 4800 0
memcheck "$out/callback" paced
memcheck "$out/blocks" --port paced --check-pattern 3 4800
kill "$sim"
wait "$sim" 2>/dev/null || true
trap 'rm -rf "$out"' EXIT
unset BASS_RUNTIME_DIR
echo "tests/c: memcheck: 0 errors in 4 test programs and 6 example runs ($((SECONDS - vg_start)) s)"
echo "tests/c: ok"
