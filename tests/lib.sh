# The shell suites' rig (sourced by tests/*/run.sh): where the built binaries are, pass/fail
# counting, the processes a suite started (stopped at exit, each bounded), a start of bassd
# that waits for its socket. A suite sets SUITE (its name in messages) before sourcing.
#   BASS_BIN_DIR  where bassd, bass and libbassclient.so are (default <target>/release)
TOP=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
TARGET=${CARGO_TARGET_DIR:-$TOP/target}
BIN=${BASS_BIN_DIR:-$TARGET/release}
: "${SUITE:=tests}"
passed=0
failed=0
FAILED=()
PIDS=()

say() { echo "$SUITE: $*"; }
# A suite that stops at its first failure says why and exits 1.
fail() { echo "$SUITE: FAIL: $*" >&2; exit 1; }
ok() { passed=$((passed + 1)); echo "ok   $*"; }
bad() { failed=$((failed + 1)); FAILED+=("$*"); echo "FAIL $*"; }

# The suite's verdict: the counts (and what failed), and a status that fails when anything did.
summary() {
  echo "$SUITE: $passed passed, $failed failed"
  local f
  for f in "${FAILED[@]}"; do echo "$SUITE:   failed: $f"; done
  [[ $failed == 0 ]]
}

# Refuses to run without the binaries `make build` makes (names relative to $BIN).
need_built() {
  local f
  for f in "$@"; do
    [[ -e "$BIN/$f" ]] || { echo "$SUITE: $BIN/$f missing; run make build (or make build-all)" >&2; exit 1; }
  done
}

# Stops every process in PIDS: SIGCONT (a test may have stopped it), SIGTERM, and SIGKILL for
# one that has not ended 3 s later; reaps them.
stop_all() {
  local p t
  for p in "${PIDS[@]}"; do kill -CONT "$p" 2>/dev/null || true; kill -TERM "$p" 2>/dev/null || true; done
  for p in "${PIDS[@]}"; do
    for t in $(seq 60); do kill -0 "$p" 2>/dev/null || break; sleep 0.05; done
    kill -0 "$p" 2>/dev/null && { echo "$SUITE: pid $p ignored SIGTERM for 3 s: SIGKILL" >&2; kill -9 "$p" 2>/dev/null || true; }
    wait "$p" 2>/dev/null || true
  done
  PIDS=()
}

# start_bassd DIR NAME [bassd options...]: bassd NAME in runtime directory DIR, its log in
# DIR/bassd-NAME.log; waits (at most 10 s) for its socket.
start_bassd() {
  local dir=$1 name=$2
  shift 2
  BASS_RUNTIME_DIR="$dir" BASS_LOG=${BASS_LOG:-warn} "$BIN/bassd" --name "$name" --rt-priority 0 "$@" \
    2>>"$dir/bassd-$name.log" &
  PIDS+=($!)
  for _ in $(seq 400); do
    [[ -S "$dir/bass-$name.sock" ]] && return 0
    sleep 0.025
  done
  echo "bassd $name did not start:"; cat "$dir/bassd-$name.log"; return 1
}
