#!/usr/bin/env bash
# tests/broker: the broker from the outside, as C users and shell users see it.
#  1. the control-plane C ABI (tests/broker/control_abi.c, strict warnings, plain and under
#     ASan/UBSan) against real bassd processes;
#  2. the bass command-line tool (devices, acquire, status, blocks, stop, errors);
#  3. several devices in one acquisition, checked against ground truth (multi.sh).
# The Rust integration tests (broker/tests/: sim devices, ALSA file and jack plugins,
# lifecycle) run with `cargo test --release --workspace`; pass --with-cargo to run them here too.
set -euo pipefail
SUITE=tests/broker
source "$(dirname "$0")/../lib.sh"
top=$TOP bin=$BIN
need_built bassd bass libbassclient.so
work=$(mktemp -d -t bass-broker-tests.XXXXXX)
trap 'stop_all; rm -rf "$work"' EXIT
cc=${CC:-cc}
flags=(-std=c11 -Wall -Wextra -Wpedantic -Werror -I "$top/include")
link=(-L "$bin" -lbassclient -Wl,-rpath,"$bin" -lpthread)
"$cc" "${flags[@]}" -O2 "$top/tests/broker/control_abi.c" -o "$work/control_abi" "${link[@]}"
variants=(control_abi)
if "$cc" "${flags[@]}" -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all \
     "$top/tests/broker/control_abi.c" -o "$work/control_abi_asan" "${link[@]}" 2>"$work/asan-build.log"; then
  variants+=(control_abi_asan)
else
  echo "note: sanitizers unavailable here; running the plain build only"
fi
for v in "${variants[@]}"; do
  d="$work/rt-$v"; mkdir -p "$d"
  # control_abi.c opens a PCM that does not exist: not a card reference, so allowed by name.
  start_bassd "$d" default --allow-device bass_no_such_pcm
  start_bassd "$d" second
  if BASS_RUNTIME_DIR="$d" ASAN_OPTIONS=detect_leaks=1 "$work/$v"; then ok "C ABI ($v)"; else bad "C ABI ($v)"; fi
done

# 2. CLI
d="$work/rt-cli"; mkdir -p "$d"
start_bassd "$d" default
bass() { BASS_RUNTIME_DIR="$d" "$bin/bass" "$@"; }
out=$(bass devices)
if grep -q '^DEVICE' <<<"$out" && grep -q '^sim:pattern  *Simulated' <<<"$out"; then ok "bass devices"; else bad "bass devices: $out"; fi
out=$(bass acquire sim:pattern --rate 8000 --frames 80 --chunks 50 --wait)
if grep -q 'epoch 1' <<<"$out" && grep -q 'first chunk published' <<<"$out"; then ok "bass acquire --wait"; else bad "bass acquire: $out"; fi
out=$(bass status)
if grep -q '^state *capturing' <<<"$out" && grep -q '8000 Hz, 2 ch, 80 frames x 50 chunks' <<<"$out"; then ok "bass status"; else bad "bass status: $out"; fi
out=$(bass blocks --block 160 --count 3)
n=$(grep -c '^block .*(160) loss 0 ' <<<"$out" || true)
if [[ $n == 3 ]]; then ok "bass blocks"; else bad "bass blocks: $out"; fi
if out=$(bass acquire sim:pattern --frames 0 2>&1); then bad "bass acquire --frames 0 succeeded"; else
  if grep -q "'--frames <N>': 0 is not in 1\.\." <<<"$out"; then ok "bass refuses a bad request"; else bad "bad request message: $out"; fi
fi
# The device policy: an ALSA plugin string runs nothing and writes nothing.
if out=$(bass acquire "file:'|touch $d/pwned',raw" 2>&1); then bad "a pipe plugin string was accepted"; else
  if grep -q 'device policy' <<<"$out" && [[ ! -e "$d/pwned" ]]; then ok "bass refuses a plugin string"; else
    bad "plugin string: $out"; fi
fi
out=$(bass stop) && out=$(bass status)
if grep -q '^state *stopped' <<<"$out"; then ok "bass stop"; else bad "bass stop: $out"; fi
if out=$(BASS_RUNTIME_DIR="$d" "$bin/bass" --name nobody status 2>&1); then bad "status of a missing broker succeeded"; else
  if grep -q 'is bassd --name nobody running' <<<"$out"; then ok "missing broker is reported"; else bad "missing broker: $out"; fi
fi

# 3. One acquisition of several sim:field cards against the analytic field (tests/broker/multi.sh).
if "$top/tests/broker/multi.sh"; then ok "several devices on one port (multi.sh)"; else bad "several devices on one port (multi.sh)"; fi

if [[ "${1:-}" == "--with-cargo" ]]; then
  if (cd "$top" && cargo test --release -p bass-broker); then ok "cargo test -p bass-broker"; else bad "cargo test -p bass-broker"; fi
fi

summary
