#!/usr/bin/env bash
# Builds the C ABI test against include/bass.h and the cdylib with strict warnings, then runs
# it plain and under AddressSanitizer + UndefinedBehaviorSanitizer.
set -euo pipefail
top=$(cd "$(dirname "$0")/../.." && pwd)
lib="${CARGO_TARGET_DIR:-$top/target}/release"
[[ -f "$lib/libbassclient.so" ]] || { echo "build first: cargo build --release" >&2; exit 1; }
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
cc=${CC:-cc}
flags=(-std=c11 -Wall -Wextra -Wpedantic -Werror -I "$top/include")
link=(-L "$lib" -lbassclient -Wl,-rpath,"$lib" -lpthread)

"$cc" "${flags[@]}" -O2 "$top/tests/c/abi_test.c" -o "$out/abi_test" "${link[@]}"
"$cc" "${flags[@]}" -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all \
  "$top/tests/c/abi_test.c" -o "$out/abi_test_asan" "${link[@]}"
# The callback stream (bass_stream_*), plain and sanitized.
"$cc" "${flags[@]}" -O2 "$top/tests/c/stream_test.c" -o "$out/stream_test" "${link[@]}"
"$cc" "${flags[@]}" -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all \
  "$top/tests/c/stream_test.c" -o "$out/stream_test_asan" "${link[@]}"
# The C stream's steady path makes no allocation (interposes malloc: no sanitizer build).
"$cc" "${flags[@]}" -O2 "$top/tests/c/stream_rt.c" -o "$out/stream_rt" "${link[@]}"
# The C++ wrapper's callback stream (include/bass.hpp), plain and sanitized.
cxxflags=(-std=c++17 -Wall -Wextra -Wpedantic -Werror -I "$top/include")
"${CXX:-c++}" "${cxxflags[@]}" -O2 "$top/tests/c/stream_test.cpp" -o "$out/stream_test_cpp" "${link[@]}"
"${CXX:-c++}" "${cxxflags[@]}" -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all \
  "$top/tests/c/stream_test.cpp" -o "$out/stream_test_cpp_asan" "${link[@]}"
# The header must also compile as C++.
printf '#include "bass.h"\nint main() { return bass_version() == nullptr; }\n' > "$out/hpp.cpp"
"${CXX:-c++}" -std=c++17 -Wall -Wextra -Wpedantic -Werror -I "$top/include" "$out/hpp.cpp" -o "$out/hpp" "${link[@]}"

# bass_port_get_info asks /proc once per writer, not once per call (strace counts the opens).
"$cc" "${flags[@]}" -O2 "$top/tests/c/info_liveness.c" -o "$out/info_liveness" "${link[@]}"
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
echo "tests/c: ok"
