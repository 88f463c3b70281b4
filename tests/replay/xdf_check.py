#!/usr/bin/env python3
"""Checks a `bass record --format xdf` file with a reader bass did not write, PyPI pyxdf
(`load_xdf` with dejitter_timestamps=False, and with its defaults: clock sync and dejittering),
against a WAV + sidecar recording of the same port made at the same time (the proven path):

- the streams: `bass` (Audio, int32, the recorded channels, the port's rate, desc naming the
  epoch and the first frame) and `bass-loss` (Markers, string, irregular);
- every sample: frame i of the XDF is frame first_frame + i + the frames the overrun markers
  before it name; it equals the WAV's frame (--wav), and every sample that is not a zero is
  the sim device's pattern(frame, channel) of its recorded channel (--channels);
- every stamp (undejittered) is its chunk's CLOCK_MONOTONIC stamp (the WAV sidecar's row)
  plus its offset at the nominal rate, within 1 us; the defaults give the same stamps
  (the stream says can_drop_samples, and every clock offset is 0);
- the markers are exactly: one `overrun` per run of frames missing from the samples (their
  frames, stamped at their first frame from the chunk after them) and one `gap` per run of
  zero-filled frames (GAP chunks, and the zeros of DISCONTINUITY chunks: bass lsl's rule on
  the WAV's rows and samples), stamped at its first frame;
- the footers (unless --killed: then there are none) give the sample counts and first/last
  stamps; ClockOffsets are 0; --recorder: the recorder's --json summary agrees.

Prints one "ok" line, or the problems and exits 1.
"""
import argparse
import importlib.metadata
import json
import os
import sys

import numpy as np
import pyxdf

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mcap_check import pattern, read_wav32  # noqa: E402

GAP, DISCONTINUITY = 1, 2


def frame_of(v):
    """The frame a pattern sample names (its low 26 bits of frame index)."""
    return ((int(v) & 0xFFFFFFFF) >> 6) & 0x03FFFFFF


def streams_of(path, **kw):
    streams, _ = pyxdf.load_xdf(path, **kw)
    audio = [s for s in streams if s["info"]["type"] == ["Audio"]]
    markers = [s for s in streams if s["info"]["type"] == ["Markers"]]
    return streams, audio, markers


def expected_gaps(wav, side, channels):
    """bass lsl's gap runs over the WAV: (first_frame, frames) of the zero-filled runs."""
    w0 = side["recording"]["first_frame"]
    nfpc = side["acquisition"]["frames_per_chunk"]
    rows = {r["first_frame"]: r for r in side["chunks"]}
    runs, run = [], None
    for i, s in enumerate(wav):
        f = w0 + i
        row = rows.get((f - 1) // nfpc * nfpc + 1)
        flags = row["flags"] if row else 0
        sel = [s[c] for c in channels] if channels is not None else list(s)
        zero = bool(flags & GAP) or (bool(flags & DISCONTINUITY) and not any(sel))
        if zero:
            run = [f, 1] if run is None else [run[0], run[1] + 1]
        elif run is not None:
            runs.append(tuple(run))
            run = None
    if run is not None:
        runs.append(tuple(run))
    return runs


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("xdf")
    ap.add_argument("--wav", required=True, help="a WAV recording of the same port with its sidecar")
    ap.add_argument("--channels", help="the port channels recorded, e.g. 1,0 [default: all]")
    ap.add_argument("--recorder", help="the recorder's --json summary")
    ap.add_argument("--expect-gap", action="store_true")
    ap.add_argument("--expect-loss", action="store_true")
    ap.add_argument("--killed", action="store_true", help="the recorder was SIGKILLed: no footers")
    a = ap.parse_args()
    problems = []
    side = json.load(open(a.wav + ".json"))
    wav = read_wav32(a.wav)
    w0 = side["recording"]["first_frame"]
    rate = side["acquisition"]["sample_rate"]
    nfpc = side["acquisition"]["frames_per_chunk"]
    rows = {r["first_frame"]: r for r in side["chunks"]}
    wlost = {f for x in side["losses"] for f in range(x["first_frame"], x["first_frame"] + x["frames"])}
    if wlost:
        problems.append(f"the WAV recording beside lost frames itself: {side['losses']}")

    streams, audio, markers = streams_of(a.xdf, dejitter_timestamps=False)
    if len(streams) != 2 or len(audio) != 1 or len(markers) != 1:
        print(f"FAIL {a.xdf}: streams {[s['info']['type'] for s in streams]}, not one Audio and one Markers")
        sys.exit(1)
    au, mk = audio[0], markers[0]
    info = au["info"]
    nch = int(info["channel_count"][0])
    channels = [int(c) for c in a.channels.split(",")] if a.channels else list(range(side["acquisition"]["channels"]))
    bass = info["desc"][0]["bass"][0]
    first = int(bass["first_frame"][0])
    want = (["bass"], ["int32"], nch, float(rate), str(side["acquisition"]["epoch"]))
    got = (info["name"], info["channel_format"], len(channels), float(info["nominal_srate"][0]), bass["epoch"][0])
    if want != got:
        problems.append(f"audio stream (name, format, channels, rate, epoch) {got}, expected {want}")
    labels = [c["label"][0] for c in info["desc"][0]["channels"][0]["channel"]]
    if labels != [f"ch{c}" for c in channels]:
        problems.append(f"channel labels {labels}, expected the recorded channels {channels}")
    if mk["info"]["name"] != ["bass-loss"] or mk["info"]["channel_format"] != ["string"] or float(mk["info"]["nominal_srate"][0]) != 0:
        problems.append(f"marker stream {mk['info']['name']} {mk['info']['channel_format']} {mk['info']['nominal_srate']}")

    data, ts = au["time_series"], au["time_stamps"]
    texts = [m[0] for m in mk["time_series"]]
    parsed = [json.loads(t) for t in texts]
    for t, p in zip(texts, parsed):
        canon = '{"first_frame":%d,"frames":%d,"cause":"%s","epoch":%d}' % (p["first_frame"], p["frames"], p["cause"], p["epoch"])
        if t != canon:
            problems.append(f"marker {t!r} is not bass lsl's JSON {canon!r}")
    overruns = sorted((p["first_frame"], p["frames"]) for p in parsed if p["cause"] == "overrun")
    gaps = [(p["first_frame"], p["frames"]) for p in parsed if p["cause"] == "gap"]

    # The frame of every sample, from the first frame and the overrun markers.
    frames, f, o = [], first, 0
    for _ in range(len(data)):
        while o < len(overruns) and overruns[o][0] == f:
            f += overruns[o][1]
            o += 1
        frames.append(f)
        f += 1
    if o != len(overruns) and overruns[o:] and overruns[o][0] != f:
        problems.append(f"overrun markers {overruns[o:]} do not fall between the samples")

    # Samples: the WAV's frame, the pattern where not zero; the stamps, the rows'.
    max_err, missing, n_pattern = 0.0, [], 0
    for i, (fr, s) in enumerate(zip(frames, data)):
        s = tuple(int(v) for v in s)
        if any(s):
            n_pattern += 1
            if s != tuple(pattern(fr, c) for c in channels):
                problems.append(f"sample {i} (frame {fr}): {s}, not the pattern {tuple(pattern(fr, c) for c in channels)}")
                break
        if not w0 <= fr < w0 + len(wav):
            missing.append(fr)
            continue
        ws = tuple(wav[fr - w0][c] for c in channels)
        if ws != s:
            problems.append(f"sample {i} (frame {fr}): {s}, the WAV has {ws}")
            break
        row = rows.get((fr - 1) // nfpc * nfpc + 1)
        if row is None:
            problems.append(f"frame {fr}: no row in the WAV's sidecar")
            break
        exp = row["mono_ns"] / 1e9 + (fr - row["first_frame"]) / rate
        max_err = max(max_err, abs(ts[i] - exp))
    if missing:
        problems.append(f"{len(missing)} frames of the XDF are not in the WAV (frames {missing[0]}..{missing[-1]})")
    if max_err > 1e-6:
        problems.append(f"a stamp is {max_err * 1e6:.3f} us from its chunk's stamp + offset / rate")

    # The overrun markers are exactly the frames missing from the samples (pattern frames).
    jumps = []
    for i in range(1, len(data)):
        pf, nf = frames[i - 1], frames[i]
        if nf != pf + 1:
            jumps.append((pf + 1, nf - pf - 1))
    if jumps != overruns:
        problems.append(f"overrun markers {overruns}; the samples jump at {jumps}")
    # A run cut by the start of the file starts at its first frame; one cut by its end ends there.
    exp_gaps = [(max(g0, first), min(g0 + gn, frames[-1] + 1) - max(g0, first)) for g0, gn in expected_gaps(wav, side, channels)
                if g0 <= frames[-1] and g0 + gn > first] if frames else []
    if gaps != exp_gaps:
        problems.append(f"gap markers {gaps}; bass lsl's rule on the WAV gives {exp_gaps}")
    # Marker stamps: a gap's first frame's; an overrun's first frame's from the chunk after it.
    for p, t in zip(parsed, mk["time_stamps"]):
        fr = p["first_frame"]
        if p["cause"] == "gap":
            row = rows.get((fr - 1) // nfpc * nfpc + 1)
        else:
            nxt = fr + p["frames"]
            row = rows.get((nxt - 1) // nfpc * nfpc + 1)
        if row is None:
            problems.append(f"marker {p}: no row to stamp it")
            continue
        exp = row["mono_ns"] / 1e9 + (fr - row["first_frame"]) / rate
        if abs(t - exp) > 1e-6:
            problems.append(f"marker {p} stamped {t:.7f}, its first frame's is {exp:.7f}")
    if a.expect_gap and not gaps:
        problems.append("no gap marker (nothing to test)")
    if a.expect_loss and not overruns:
        problems.append("no overrun marker (nothing to test)")

    # Footers, clock offsets.
    for s, what in [(au, "audio"), (mk, "markers")]:
        footer = s.get("footer")
        if a.killed:
            if footer is not None:
                problems.append(f"{what}: a footer after a SIGKILL")
            continue
        if footer is None:
            problems.append(f"{what}: no footer")
            continue
        fi = footer["info"]
        n = len(s["time_stamps"])
        if int(fi["sample_count"][0]) != n:
            problems.append(f"{what} footer: sample_count {fi['sample_count']}, {n} samples")
        if n and (abs(float(fi["first_timestamp"][0]) - s["time_stamps"][0]) > 1e-6
                  or abs(float(fi["last_timestamp"][0]) - s["time_stamps"][-1]) > 1e-6):
            problems.append(f"{what} footer: stamps {fi['first_timestamp']}..{fi['last_timestamp']}, the samples {s['time_stamps'][0]}..{s['time_stamps'][-1]}")
        if any(v != 0 for v in s["clock_values"]) or len(s["clock_times"]) < 2 or np.any(np.diff(s["clock_times"]) <= 0):
            problems.append(f"{what}: clock offsets {list(zip(s['clock_times'], s['clock_values']))}")

    # pyxdf's defaults: the same samples, the same stamps (can_drop_samples; offsets 0).
    _, audio2, markers2 = streams_of(a.xdf)
    d_err = float(np.max(np.abs(audio2[0]["time_stamps"] - ts))) if len(ts) else 0.0
    if d_err > 1e-6 or not np.array_equal(audio2[0]["time_series"], data):
        problems.append(f"pyxdf's defaults move the stamps by {d_err * 1e6:.3f} us or change the samples")
    if [m[0] for m in markers2[0]["time_series"]] != texts or float(np.max(np.abs(markers2[0]["time_stamps"] - mk["time_stamps"]), initial=0)) > 1e-6:
        problems.append("pyxdf's defaults change the markers")

    if a.recorder:
        r = json.load(open(a.recorder))
        lost = sum(n for _, n in overruns)
        if (r["frames"], r["lost_frames"], r["first_frame"]) != (len(data) + lost, lost, first):
            problems.append(f"the recorder says frames {r['frames']}, lost {r['lost_frames']}, first {r['first_frame']}; the file holds {len(data)} samples + {lost} lost from {first}")

    if problems:
        print(f"FAIL {a.xdf}:\n  " + "\n  ".join(problems))
        sys.exit(1)
    print(f"ok: pyxdf {importlib.metadata.version('pyxdf')}: {len(data)} samples x {nch} ch (frames {first}..{frames[-1] if frames else first}, {n_pattern} the pattern, "
          f"the rest zeros), equal to the WAV's; stamps within {max_err * 1e9:.1f} ns of chunk stamp + offset/rate (defaults: {d_err * 1e9:.1f} ns more); "
          f"markers exactly {len(overruns)} overrun {overruns} and {len(gaps)} gap {gaps}")


if __name__ == "__main__":
    main()
