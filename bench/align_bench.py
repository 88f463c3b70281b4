#!/usr/bin/env python3
"""bass-bench part 8's reader (bench/src/align.rs): reads a several-device sim:field
acquisition of broker NAME for SECONDS through the Python binding and measures each follower
against the analytic field (align::sim::Field::standard; docs/multi-device.md, "Simulated cards
with ground truth"): lock (the mask bits, and the residual staying within 0.25 sample),
residual alignment from the pilots' phase per 10 ms block after lock (RMS, p99.9, samples),
SNR of the aligned channels against the field, ratio noise (Status ratio_ppm, 1 s windows),
the delay from a chunk's first-frame stamp plus its duration to the reader having it (chunks
the reader waited for); and, for followers without
slew, the floor: the same follower stream (the field at the card's own instants) resampled by
PyPI soxr (VHQ) with the true constant ratio, against the field.

Usage: align_bench.py NAME SECONDS FOLLOWERS_JSON   (a list of {ppm, slew, offset_us, ch})
Prints one JSON object.
"""
import json
import math
import sys
import time

import numpy as np

import bass

RATE = 48000
NFPC = 480
TONES = [(997.0, 0.25, 0.3, 0.7), (3000.0, 0.2, 1.1, 1.9), (211.0, 0.12, 2.0, 0.4),
         (1723.0, 0.1, 0.5, 2.6), (5417.0, 0.08, 4.0, 1.2), (9001.0, 0.06, 3.3, 0.9),
         (15101.0, 0.04, 5.1, 2.2)]
FULL = 2.0 ** 31


# The residual "settled": from when the aligner's 20 s long window of stamps is full.
SETTLED_S = 22.0


def field(ch, t):
    return sum(a * np.sin(2 * np.pi * hz * t + ph + ch * cph) for hz, a, ph, cph in TONES)


def pilot_shift(y, t, ch):
    """Time shift of block y (field times t) against the field, samples (the pilots' phase)."""
    cols = []
    for hz, _, _, _ in TONES:
        w = 2 * np.pi * hz * t
        cols += [np.sin(w), np.cos(w)]
    a = np.stack(cols, axis=1)
    x, *_ = np.linalg.lstsq(a, y, rcond=None)
    s = []
    for i, (hz, _, ph, cph) in enumerate(TONES[:2]):
        d = (math.atan2(x[2 * i + 1], x[2 * i]) - (ph + ch * cph) + math.pi) % (2 * math.pi) - math.pi
        s.append(d / (2 * math.pi * hz) * RATE)
    return sum(s) / len(s)


def snr_db(y, e):
    return 10 * math.log10(float(np.sum(e * e)) / max(float(np.sum((y - e) ** 2)), 1e-300))


def soxr_floor(f, seconds=8.0):
    import soxr
    fs_in = RATE * (1 + f["ppm"] * 1e-6)
    n = np.arange(int(seconds * fs_in))
    off = f["offset_us"] * 1e-6
    out = []
    for c in range(2):
        x = field(f["ch"] + c, off + n / fs_in)
        y = soxr.resample(x, fs_in, RATE, quality="VHQ")
        j = np.arange(len(y))
        e = field(f["ch"] + c, off + j / RATE)
        m = slice(RATE // 2, len(y) - RATE // 2)
        out.append((y[m], e[m]))
    return snr_db(np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out]))


def main():
    name, seconds, followers = sys.argv[1], float(sys.argv[2]), json.loads(sys.argv[3])
    port = bass.Port(name)
    nch = 2 + 2 * len(followers)
    assert port.channels == nch, f"{port.channels} channels, not {nch}"
    end = int(seconds * RATE) // NFPC * NFPC
    data = np.zeros((nch, end))
    masks = []
    delays = []
    ratios = [[] for _ in followers]
    nfr, lost = 1, 0
    while nfr <= end:
        before = time.clock_gettime_ns(time.CLOCK_MONOTONIC)
        port.wait(nfr + NFPC - 1, timeout=10.0)
        now = time.clock_gettime_ns(time.CLOCK_MONOTONIC)
        d, nfr2, n, loss = port.get_audio_data_multi(NFPC, nfr)
        lost += loss
        first = nfr2 - n
        if first - 1 + n > end:
            n = end - (first - 1)
        data[:, first - 1:first - 1 + n] = d[:, :n]
        info = port.chunk_info(first)
        masks.append((first, info.missing_channels | info.unaligned_channels))
        if now - before > 500_000 and nfr2 - nfr <= NFPC:
            # The reader was waiting for this chunk (not catching up): its publication delay.
            delays.append((now - info.mono_ns) * 1e-9 - NFPC / RATE)
        if len(masks) % 10 == 0:
            for i, dev in enumerate(bass.devices(name)[1:]):
                ratios[i].append(((first - 1) / RATE, dev["ratio_ppm"]))
        nfr = nfr2
    t = np.mod(np.arange(end) / RATE, 1.0)
    out = {"lost": lost, "delay_median_ms": float(np.median(delays)) * 1e3 if delays else None,
           "delay_p99_ms": float(np.quantile(delays, 0.99)) * 1e3 if delays else None, "followers": []}
    for i, f in enumerate(followers):
        bits = 0b11 << (2 + 2 * i)
        first_ok = next((c for c, m in masks if not m & bits), None)
        r = {"ppm": f["ppm"], "slew": f["slew"]}
        if first_ok is None:
            r["lock_s"] = None
            out["followers"].append(r)
            continue
        lock = first_ok - 1
        r["lock_s"] = lock / RATE
        bad_after = any(m & bits for c, m in masks if c > first_ok)
        r["lost_lock"] = bad_after
        pc = 2 + 2 * i
        res, blocks_t = [], []
        for b in range(0, end - NFPC + 1, NFPC):
            s = 0.0
            for c in range(2):
                s += pilot_shift(data[pc + c, b:b + NFPC] / FULL, t[b:b + NFPC], f["ch"] + c)
            res.append(s / 2)
            blocks_t.append(b / RATE)
        res, blocks_t = np.array(res), np.array(blocks_t)
        over = np.nonzero(np.abs(res) > 0.25)[0]
        r["lock_025_s"] = float(blocks_t[over[-1]] + NFPC / RATE) if len(over) else 0.0
        after = res[blocks_t >= r["lock_s"]]
        r["rms"] = float(np.sqrt(np.mean(after ** 2)))
        r["p999"] = float(np.quantile(np.abs(after), 0.999))
        # Once the aligner's long window (20 s of stamps, align/src/timeline.rs) is full.
        settled = res[blocks_t >= SETTLED_S]
        r["rms_settled"] = float(np.sqrt(np.mean(settled ** 2))) if len(settled) else None
        r["p999_settled"] = float(np.quantile(np.abs(settled), 0.999)) if len(settled) else None
        ys, es = [], []
        for c in range(2):
            ys.append(data[pc + c, lock:] / FULL)
            es.append(field(f["ch"] + c, t[lock:]))
        r["snr_db"] = snr_db(np.concatenate(ys), np.concatenate(es))
        r["soxr_db"] = soxr_floor(f) if f["slew"] == 0 else None
        q = np.array([x for x in ratios[i] if x[0] >= r["lock_s"]])
        noise = []
        if len(q) >= 6:
            for w0 in np.arange(q[0, 0], q[-1, 0] - 1.0, 1.0):
                m = (q[:, 0] >= w0) & (q[:, 0] < w0 + 1.0)
                if m.sum() >= 4:
                    p = np.polyfit(q[m, 0], q[m, 1], 1)
                    noise.append(float(np.std(q[m, 1] - np.polyval(p, q[m, 0]))))
        r["ratio_noise_ppm"] = float(np.mean(noise)) if noise else None
        r["ratio_last_ppm"] = float(q[-1, 1]) if len(q) else None
        out["followers"].append(r)
    print(json.dumps(out))


if __name__ == "__main__":
    sys.exit(main())
