#!/usr/bin/env bash
# The fault and abuse suite (docs/reliability.md). Run by `make test-faults`; builds through
# `make build-all`. Honours $CARGO_TARGET_DIR (default target/).
#
#   1. the Rust fault tests (tests/faults/tests/t*.rs, #[ignore]d in plain `cargo test`),
#      one at a time, in release;
#   2. the corrupted-port tests again in a debug build (overflow checks on);
#   3. the C ABI abuse program (tests/faults/c/abi_abuse.c) plain, under
#      AddressSanitizer + UndefinedBehaviorSanitizer, and under ThreadSanitizer;
#   4. Miri on the heap-backed ring, when the toolchain has it (optional);
#   5. opt-in (BASS_FAULTS_RUST_TSAN=1): ThreadSanitizer on the whole Rust library.
#
# Every test prints its measured figures as `FIGURE item N: ...`; they are collected in
# $CARGO_TARGET_DIR/faults/figures.txt and printed at the end.
# Knobs: BASS_FAULTS_TORN_SECS (60), BASS_FAULTS_SOAK_FRAMES (4.5e9), BASS_FAULTS_KILLS (100),
# BASS_FAULTS_SEED, BASS_FAULTS_MIRI=0 to skip Miri.
set -euo pipefail
SUITE=faults
source "$(dirname "$0")/../lib.sh"
top=$TOP target=$TARGET
cd "$top"
export CARGO_TARGET_DIR="$target"
cargo=${CARGO:-cargo}
out="$target/faults"
rm -rf "$out"
mkdir -p "$out"
log="$out/log.txt"
t0=$SECONDS

step() { # name, command...
  local name=$1
  shift
  local s=$SECONDS
  echo "== faults: $name"
  last_ok=0
  if "$@" 2>&1 | tee -a "$log"; then
    last_ok=1
    ok "$name ($((SECONDS - s)) s)"
  else
    bad "$name ($((SECONDS - s)) s)"
  fi
}

# The library (its cdylib for the C programs), bassd and bass, the agent and the tests: the
# one build of the workspace every suite uses.
make -C "$top" --no-print-directory build-all
step "rust fault tests (release)" \
  "$cargo" test --release -p bass-faults -- --include-ignored --nocapture --test-threads=1
step "corrupted ports (debug build, overflow checks)" \
  "$cargo" test -p bass-faults --test corrupt_ports -- --ignored --nocapture --test-threads=1

# The C ABI under sanitizers. The Rust library itself is not instrumented: ASan/UBSan/TSan
# check the C side of every call (and libc calls the library makes, e.g. memcpy, through
# ASan's interceptors); guard pages catch any write or read past a caller's buffer whatever
# the instrumentation.
lib="$target/release"
cc=${CC:-cc}
cflags=(-std=c11 -Wall -Wextra -Wpedantic -Werror -I "$top/include")
link=(-L "$lib" -lbassclient -Wl,-rpath,"$lib" -lpthread)
src="$top/tests/faults/c/abi_abuse.c"
run_c() { # binary, env...
  local bin=$1
  shift
  local rt
  rt=$(mktemp -d "${TMPDIR:-/tmp}/bass-faults-c.XXXXXX")
  env BASS_RUNTIME_DIR="$rt" "$@" "$bin"
  local rc=$?
  rm -rf "$rt"
  return $rc
}
"$cc" "${cflags[@]}" -O2 "$src" -o "$out/abi_abuse" "${link[@]}"
step "C ABI abuse (plain)" run_c "$out/abi_abuse"
"$cc" "${cflags[@]}" -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all "$src" \
  -o "$out/abi_abuse_asan" "${link[@]}"
step "C ABI abuse (ASan + UBSan)" run_c "$out/abi_abuse_asan" \
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=0:exitcode=86 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
((last_ok)) && echo "FIGURE item 6: AddressSanitizer + UndefinedBehaviorSanitizer (leak check on): 0 reports" | tee -a "$log"
if "$cc" -fsanitize=thread -x c - -o "$out/tsan-probe" <<<'int main(void){return 0;}' 2>/dev/null \
   && "$out/tsan-probe"; then
  "$cc" "${cflags[@]}" -O1 -g -fsanitize=thread "$src" -o "$out/abi_abuse_tsan" "${link[@]}"
  step "C ABI abuse (TSan)" run_c "$out/abi_abuse_tsan" TSAN_OPTIONS=halt_on_error=1:exitcode=66
  ((last_ok)) && echo "FIGURE item 12: ThreadSanitizer on the C ABI abuse program (4 threads sharing a bass_port, 2 sharing a bass_writer, close while in use): 0 reports (the Rust library is not instrumented)" | tee -a "$log"
else
  echo "FIGURE item 12: SKIPPED ThreadSanitizer: $cc cannot build/run -fsanitize=thread here" | tee -a "$log"
fi

# Miri on the heap-backed ring (optional: needs a nightly toolchain with miri and rust-src).
if [[ "${BASS_FAULTS_MIRI:-1}" != 0 ]] && "$cargo" +nightly miri --version >/dev/null 2>&1; then
  step "Miri: heap-backed ring" env CARGO_TARGET_DIR="$target/miri" \
    "$cargo" +nightly miri test -p bass-faults --test miri_ring -- --nocapture
  ((last_ok)) && echo "FIGURE item 12: Miri: the heap-backed ring test ran with 0 undefined-behaviour or data-race reports" | tee -a "$log"
else
  echo "FIGURE item 12: SKIPPED Miri: no nightly toolchain with miri here (rustup toolchain install nightly --component miri rust-src; then: cargo +nightly miri test -p bass-faults --test miri_ring)" | tee -a "$log"
fi

# ThreadSanitizer on the whole Rust library (opt-in: rebuilds std with the sanitizer, a few
# minutes on 2 cores): BASS_FAULTS_RUST_TSAN=1 with a nightly toolchain that has rust-src.
if [[ "${BASS_FAULTS_RUST_TSAN:-0}" == 1 ]]; then
  step "ThreadSanitizer: Rust library (nightly, -Zbuild-std)" env CARGO_TARGET_DIR="$target/tsan" \
    RUSTFLAGS="-Zsanitizer=thread" TSAN_OPTIONS=halt_on_error=1 \
    "$cargo" +nightly test -Zbuild-std --target "$(rustc -vV | sed -n 's/^host: //p')" \
    -p bass-faults --test miri_ring -- --nocapture
  ((last_ok)) && echo "FIGURE item 12: ThreadSanitizer on the instrumented Rust library (heap ring + mapped port, writer and reader threads): 0 reports" | tee -a "$log"
else
  echo "FIGURE item 12: Rust-side ThreadSanitizer not run (opt-in: BASS_FAULTS_RUST_TSAN=1, needs nightly + rust-src)" | tee -a "$log"
fi

grep -ho 'FIGURE item .*' "$log" | sort -s -t: -k1,1V > "$out/figures.txt" || true
echo
echo "== faults: measured figures ($out/figures.txt)"
cat "$out/figures.txt"
echo "== faults: $((SECONDS - t0)) s"
summary
