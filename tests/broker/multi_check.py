#!/usr/bin/env python3
"""Checks a several-device acquisition of sim:field cards against the analytic field
(docs/multi-device.md), reading the port of broker NAME through the Python binding.

The acquisition (started by tests/broker/multi.sh): a master sim:field (0 ppm, field channels
0-1), follower 1 (+87 ppm, field channels 0-1, port channels 2-3), follower 2 (-143 ppm, field
channels 2-3, port channels 4-5) with an xrun at XRUN_S, unplugged at UNPLUG_S, replugged at
REPLUG_S. The checker computes the expected signal itself, from the field's definition (the
tones below, the same as align::sim::Field::standard) and the master's frame index: a sim:field
card's frame 0 is at a whole second of CLOCK_MONOTONIC and the field repeats every second, so
master frame k (from 1) was sampled at field time (k - 1) / RATE.

Usage: multi_check.py NAME SECONDS XRUN_S UNPLUG_S REPLUG_S
Prints a summary line `MULTI ...` and exits 1 with the failures named.
"""
import math
import sys

import numpy as np

import bass

RATE = 48000
NFPC = 480
# (Hz, amplitude, phase, phase per channel): align::sim::Field::standard.
TONES = [(997.0, 0.25, 0.3, 0.7), (3000.0, 0.2, 1.1, 1.9), (211.0, 0.12, 2.0, 0.4),
         (1723.0, 0.1, 0.5, 2.6), (5417.0, 0.08, 4.0, 1.2), (9001.0, 0.06, 3.3, 0.9),
         (15101.0, 0.04, 5.1, 2.2)]
FULL = 2.0 ** 31
MAX_SLOPE = sum(a * 2 * math.pi * hz for hz, a, _, _ in TONES)
# The documented bound (docs/multi-device.md, align/tests/aligned.rs): an aligned sample of a
# locked follower lies within the field's largest slope times 0.5 sample (the lock threshold of
# the p99.9 error estimate), plus the resampler's own 1e-5.
MISALIGN_BOUND = 0.5
BOUND = MAX_SLOPE * MISALIGN_BOUND / RATE + 1e-5
# Port channels of each device: (first, field channel of the first).
MASTER, F1, F2 = (0, 0), (2, 0), (4, 2)
MASK = {"f1": 0b1100, "f2": 0b110000}


def field(ch, t):
    return sum(a * np.sin(2 * np.pi * hz * t + ph + ch * cph) for hz, a, ph, cph in TONES)


def main():
    name, seconds, xrun_s, unplug_s, replug_s = sys.argv[1], float(sys.argv[2]), *map(float, sys.argv[3:6])
    port = bass.Port(name)
    assert port.channels == 6, f"the port has {port.channels} channels, not 6"
    end = int(seconds * RATE) // NFPC * NFPC
    nfr = 1
    fails = []
    worst = {"f1": 0.0, "f2": 0.0}
    aligned = {"f1": 0, "f2": 0}
    chunks = []  # (first frame, missing mask, unaligned mask, flags)
    master_worst = 0
    while nfr <= end:
        port.wait(nfr + 10 * NFPC - 1, timeout=10.0)
        data, nfr2, n, loss = port.get_audio_data_multi(10 * NFPC, nfr)
        if loss:
            fails.append(f"{loss} frames lost before frame {nfr}: the checker fell behind")
        first = nfr2 - n
        k = np.arange(first, first + n, dtype=np.float64)
        t = np.mod((k - 1) / RATE, 1.0)
        m = np.array([field(MASTER[1] + c, t) for c in range(2)]) * FULL
        master_worst = max(master_worst, float(np.max(np.abs(data[0:2] - np.round(m)))))
        for c0 in range(first, first + n, NFPC):
            info = port.chunk_info(c0)
            chunks.append((c0, info.missing_channels, info.unaligned_channels, info.flags))
            j = slice(c0 - first, c0 - first + NFPC)
            for key, (pc, fc) in (("f1", F1), ("f2", F2)):
                if (info.missing_channels | info.unaligned_channels) & MASK[key]:
                    continue
                e = np.array([field(fc + c, t[j]) for c in range(2)])
                y = data[pc:pc + 2, j] / FULL
                d = float(np.max(np.abs(y - e)))
                worst[key] = max(worst[key], d)
                aligned[key] += NFPC
                if d > BOUND:
                    fails.append(f"{key}: chunk at frame {c0} ({(c0 - 1) / RATE:.2f} s) is {d:.3e} off the "
                                 f"field, over the bound {BOUND:.3e} ({d / MAX_SLOPE * RATE:.3f} sample)")
        nfr = nfr2
    if master_worst > 2:
        fails.append(f"the master's channels are {master_worst} LSB off the field: the checker's time "
                     "model (frame 0 at a whole second) does not hold")

    def at(s):
        return int(s * RATE)

    def flagged(key, lo, hi, which):
        return [c for c in chunks if at(lo) <= c[0] < at(hi) and c[which] & MASK[key]]

    for key in ("f1", "f2"):
        if not flagged(key, 0, 1, 2):
            fails.append(f"{key}: no chunk before its lock carries the unaligned bits")
    if not [c for c in chunks if not (c[1] | c[2]) & MASK["f1"]]:
        fails.append("f1: never locked")
    # The xrun and the unplug mark exactly follower 2's channels.
    # A card's event times count from its start, up to 1 s before the master's frame 1 (the next
    # whole second): the windows below hold the event whatever that second.
    for what, lo, hi in (("xrun", xrun_s - 1.0, xrun_s + 1.0), ("unplug", unplug_s, replug_s - 1.0)):
        marked = flagged("f2", lo, hi, 1)
        if not marked:
            fails.append(f"f2: no chunk marked missing after its {what} at {lo} s")
        wrong = [c for c in marked if c[1] & ~MASK["f2"]]
        if wrong:
            fails.append(f"f2 {what}: chunks mark other channels missing too, e.g. frame {wrong[0][0]} "
                         f"mask {wrong[0][1]:#x}")
        gap = [c for c in marked if c[3] & bass.CHUNK_FLAGS["GAP"]]
        if gap:
            fails.append(f"f2 {what}: a follower's loss made a whole-chunk GAP at frame {gap[0][0]}")
    relocked = [c for c in chunks if c[0] >= at(replug_s) and not (c[1] | c[2]) & MASK["f2"]]
    if not relocked:
        fails.append(f"f2: not locked again after its replug at {replug_s} s")
    # Lock time: the first chunk without the unaligned bits.
    lock_s = {}
    for key in ("f1", "f2"):
        c = next((c for c in chunks if not (c[1] | c[2]) & MASK[key]), None)
        lock_s[key] = None if c is None else (c[0] - 1) / RATE
    relock_s = None if not relocked else (relocked[0][0] - 1) / RATE - replug_s
    # Per device through the C export (bass_broker_device_info), as Python shows it.
    devs = bass.devices(name)
    rows = [(d["role"], d["first_channel"], d["channels"]) for d in devs]
    if rows != [("master", 0, 2), ("follower", 2, 2), ("follower", 4, 2)]:
        fails.append(f"bass.devices: {rows}")
    elif (devs[2]["xruns"], devs[2]["unplugs"], devs[1]["xruns"], devs[1]["unplugs"]) != (1, 1, 0, 0):
        fails.append(f"bass.devices counters: {devs[1:]}")
    print("MULTI lock_s f1 %s f2 %s; relock after replug %s s; worst residual f1 %.4f f2 %.4f sample "
          "(bound %.2f); aligned frames checked f1 %d f2 %d" % (
              lock_s["f1"], lock_s["f2"], None if relock_s is None else round(relock_s, 2),
              worst["f1"] / MAX_SLOPE * RATE, worst["f2"] / MAX_SLOPE * RATE, MISALIGN_BOUND,
              aligned["f1"], aligned["f2"]))
    for f in fails[:10]:
        print("FAIL", f)
    if len(fails) > 10:
        print("FAIL ... %d failures in all; the last: %s" % (len(fails), fails[-1]))
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
