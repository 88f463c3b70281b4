#!/usr/bin/env bash
# tests/broker/multi.sh: one acquisition of three sim:field cards (a master, followers at +87 and
# -143 ppm) on one bassd; the port read through the Python binding and every aligned follower
# sample checked against the analytic field by tests/broker/multi_check.py (which computes the
# field itself); follower 2's xrun and unplug/replug marked on exactly its channels, counted in
# Status, and re-locked (docs/multi-device.md). About 35 s.
set -euo pipefail
SUITE=tests/broker/multi
source "$(dirname "$0")/../lib.sh"
need_built bassd bass libbassclient.so
work=$(mktemp -d -t bass-multi.XXXXXX)
trap 'stop_all; rm -rf "$work"' EXIT
# Real-time priority where permitted (root in CI) keeps a loaded machine from starving the
# capture threads; --stall-ms: a starved thread is not a stalled device here.
start_bassd "$work" multi --rt-priority 50 --stall-ms 10000
bass() { BASS_RUNTIME_DIR="$work" "$BIN/bass" --name multi "$@"; }
SECONDS_RUN=32 XRUN=6 UNPLUG=9 REPLUG=11
master='sim:field?jitter_us=100&seed=1'
f1='sim:field?ppm=87&offset_us=3130&jitter_us=100&seed=2'
f2="sim:field?ppm=-143&offset_us=7770&jitter_us=100&seed=3&ch=2&xrun_at_s=$XRUN&unplug_at_s=$UNPLUG&replug_at_s=$REPLUG"

# Bad sim:field parameters are refused, naming the bad value; nothing starts.
if out=$(bass acquire 'sim:field?ppm=fast' 2>&1); then bad "sim:field?ppm=fast accepted"; else
  if grep -q 'ppm="fast" is not a number' <<<"$out"; then ok "a bad sim:field value is named"; else bad "bad value: $out"; fi
fi
if out=$(bass acquire sim:field 'sim:field?wobble=1' 2>&1); then bad "sim:field?wobble accepted"; else
  if grep -q 'follower 1: sim:field has no parameter "wobble"' <<<"$out"; then ok "a bad follower is named"; else bad "bad follower: $out"; fi
fi

out=$(bass acquire "$master" "$f1" "$f2" --rate 48000 --frames 480 --chunks 500 --channels 2)
if grep -q "acquiring $master + $f1 + " <<<"$out"; then ok "bass acquire of three devices"; else bad "acquire: $out"; fi
if BASS_RUNTIME_DIR="$work" PYTHONPATH="$TOP/python" BASS_LIB="$BIN/libbassclient.so" \
     python3 "$TOP/tests/broker/multi_check.py" multi "$SECONDS_RUN" "$XRUN" "$UNPLUG" "$REPLUG" >"$work/check.out"; then
  ok "aligned followers against the field, flags, re-lock"
else
  bad "multi_check: $(cat "$work/check.out")"
fi
grep '^MULTI' "$work/check.out" || true

# The counters: per device, in Status.
bass status --json >"$work/status.json"
if python3 - "$work/status.json" "$UNPLUG" "$REPLUG" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
unplugged = (float(sys.argv[3]) - float(sys.argv[2]) - 0.5) * 48000
d = s["devices"]
want = [("master", 0, 0), ("follower", 2, 0), ("follower", 4, 0)]
assert [(x["role"], x["first_channel"]) for x in d] == [w[:2] for w in want], d
m, f1, f2 = d
assert (f1["xruns"], f1["unplugs"]) == (0, 0) and f1["locks"] >= 1 and f1["state"] == "locked", f1
assert (f2["xruns"], f2["unplugs"]) == (1, 1) and f2["locks"] >= 1 and f2["state"] == "locked", f2
assert f2["missing_frames"] >= unplugged, f2
assert f2["missing_frames"] > f1["missing_frames"], (f1, f2)
assert abs(f1["ratio_ppm"] - 87) < 5 and abs(f2["ratio_ppm"] + 143) < 5, (f1["ratio_ppm"], f2["ratio_ppm"])
print("MULTI counters f1 %s; f2 %s" % ({k: f1[k] for k in ("locks", "xruns", "unplugs", "missing_frames", "ratio_ppm", "error_estimate")},
                                      {k: f2[k] for k in ("locks", "xruns", "unplugs", "missing_frames", "ratio_ppm", "error_estimate")}))
PY
then ok "per-device counters in bass status --json"; else bad "counters: $(cat "$work/status.json")"; fi
out=$(bass status)
if grep -q '^  follower sim:field?ppm=-143.*ch 4\.\.6: ' <<<"$out"; then ok "bass status per device"; else bad "status: $out"; fi

# A channel count per device from Python (bass_acquire_devices_channels): 2 + 4 channels.
if out=$(BASS_RUNTIME_DIR="$work" PYTHONPATH="$TOP/python" BASS_LIB="$BIN/libbassclient.so" python3 - <<'PY' 2>&1
import bass
bass.acquire(["sim:field", "sim:field?ppm=87"], 48000, 480, 100, channels=[2, 4], broker="multi")
rows = [(d["role"], d["first_channel"], d["channels"]) for d in bass.devices("multi")]
assert rows == [("master", 0, 2), ("follower", 2, 4)], rows
try:
    bass.acquire(["sim:field", "sim:field"], 48000, 480, 100, channels=[2], broker="multi")
    raise SystemExit("a list of 1 count for 2 devices was accepted")
except ValueError as e:
    assert "a list of 1 count(s) needs as many devices" in str(e), e
print("ok")
PY
); then ok "per-device channel counts from Python"; else bad "per-device channels: $out"; fi
summary
