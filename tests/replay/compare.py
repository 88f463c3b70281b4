#!/usr/bin/env python3
"""Checks what a client read from a replay (tests/replay/port_dump.c's output) against the
recording it replays (WAV + sidecar), with a WAV parser of its own (no bass code):

- every frame read inside the recording holds the recorded samples, at the recorded index
  (16/24-bit recordings left-justified to 32 bits, as the replay publishes them); frames read
  after the last recorded one complete its chunk and are zeros; no frame before it is read;
- every recorded frame the recorder did not lose is read;
- the losses the client saw are exactly: the frames before the recording (one loss at frame
  1), then each loss of the sidecar, at its frame and of its length;
- every chunk read has the recorded flags and CLOCK_REALTIME time, and CLOCK_MONOTONIC times
  spaced as recorded (one constant offset); a chunk without a row is TIME_ESTIMATED;
- every chunk read has the recorded timestamp bound (a row without `bound_ns`: not known,
  2^64-1) and channel masks (absent: 0), read through bass_port_chunk_ext; a chunk without a
  row has neither.

Usage: compare.py FILE.wav DUMP [--renumbered]. Prints one "ok" line or the problems (exit 1).
"""
import json
import struct
import sys

GAP, TIME_ESTIMATED, LATE = 1, 4, 8
UNKNOWN = 2**64 - 1  # BASS_BOUND_UNKNOWN


def read_wav(path):
    """(bits, channels, frames as tuples of left-justified ints) of a PCM or extensible WAV."""
    data = open(path, "rb").read()
    if data[:4] != b"RIFF" or data[8:12] != b"WAVE":
        sys.exit(f"{path}: not a RIFF/WAVE file")
    pos, fmt, body = 12, None, None
    while pos + 8 <= len(data):
        cid, size = data[pos:pos + 4], struct.unpack_from("<I", data, pos + 4)[0]
        if cid == b"fmt ":
            fmt = data[pos + 8:pos + 8 + size]
        elif cid == b"data":
            body = data[pos + 8:pos + 8 + size]
            break
        pos += 8 + size + (size & 1)
    if fmt is None or body is None:
        sys.exit(f"{path}: no fmt or data chunk")
    tag, nch, _rate, _bps, align, bits = struct.unpack_from("<HHIIHH", fmt)
    if tag not in (1, 0xFFFE) or bits not in (16, 24, 32):
        sys.exit(f"{path}: format tag {tag:#x}, {bits} bits: not integer PCM")
    width = bits // 8
    frames = []
    for off in range(0, len(body) - align + 1, align):
        row = []
        for c in range(nch):
            b = body[off + c * width:off + (c + 1) * width]
            v = int.from_bytes(b, "little", signed=True)
            row.append((v << (32 - bits)) & 0xFFFFFFFF)
        frames.append(tuple(x - (1 << 32) if x >= 1 << 31 else x for x in row))
    return bits, nch, frames


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    renumbered = "--renumbered" in sys.argv
    if len(args) != 2:
        sys.exit(__doc__)
    wav, dump = args
    side = json.load(open(wav + ".json"))
    rec, acq = side["recording"], side["acquisition"]
    bits, nch, frames = read_wav(wav)
    rec_first = rec["first_frame"]
    first = 1 if renumbered else rec_first
    shift = rec_first - first  # recorded index = port index + shift
    last = first + len(frames) - 1
    nfpc = acq["frames_per_chunk"]
    lost = [(l["first_frame"] - shift, l["frames"]) for l in side["losses"]]
    lost_set = {f for a, n in lost for f in range(a, a + n)}
    rows = {r["first_frame"] - shift: r for r in side["chunks"]}
    problems, reads, chunks, got = [], [], [], {}
    end = None
    for line in open(dump):
        w = line.split()
        if w[0] == "read":
            reads.append((int(w[1]), int(w[2]), int(w[3])))
        elif w[0] == "chunk":
            chunks.append(tuple(int(x) for x in w[1:8]))
        elif w[0] == "chunk-missing":
            problems.append(f"no chunk info for the chunk at frame {w[1]} (result {w[2]})")
        elif w[0] == "frame":
            got[int(w[1])] = tuple(int(x) for x in w[2:])
        elif w[0] == "end":
            end = (int(w[1]), w[2])
    if end is None:
        problems.append("the dump has no end line (the reader did not see the replay end)")
    for f, s in sorted(got.items()):
        if f < first:
            problems.append(f"frame {f} was read; the recording starts at frame {first}")
        elif f <= last:
            if f in lost_set:
                problems.append(f"frame {f} was read; the recorder lost it")
            elif s != frames[f - first]:
                problems.append(f"frame {f}: read {s}, recorded {frames[f - first]}")
        elif (f - 1) // nfpc != (last - 1) // nfpc or any(s):
            problems.append(f"frame {f} after the recording's last frame {last}: {s}")
        if len(problems) > 20:
            break
    missing = [f for f in range(first, last + 1) if f not in got and f not in lost_set]
    if missing:
        problems.append(f"{len(missing)} recorded frames never read, the first {missing[:5]}")
    losses = [(nfr, loss) for nfr, _, loss in reads if loss > 0]
    want = ([(1, first - 1)] if first > 1 else []) + lost
    if losses != want:
        problems.append(f"losses seen {losses}; the recording has {want}")
    offsets = set()
    n_gap = n_late = n_bound = 0
    for c0, flags, mono, rt, bound, missing, unaligned in chunks:
        r = rows.get(c0)
        if r is None:
            if not renumbered and not flags & TIME_ESTIMATED:
                problems.append(f"chunk {c0}: no row in the sidecar, yet flags {flags} lack TIME_ESTIMATED")
            if (bound, missing, unaligned) != (UNKNOWN, 0, 0):
                problems.append(f"chunk {c0}: no row, yet bound {bound} and masks {missing}, {unaligned}")
            continue
        # The row's bound (absent: not known) and masks (absent: 0), as recorded.
        want = (r.get("bound_ns", UNKNOWN), r.get("missing_channels", 0), r.get("unaligned_channels", 0))
        if (bound, missing, unaligned) != want:
            problems.append(f"chunk {c0}: bound and masks {(bound, missing, unaligned)}, recorded {want}")
        n_bound += bound != UNKNOWN
        if flags != r["flags"]:
            problems.append(f"chunk {c0}: flags {flags}, recorded {r['flags']}")
        if rt != r["realtime_ns"]:
            problems.append(f"chunk {c0}: CLOCK_REALTIME {rt}, recorded {r['realtime_ns']}")
        offsets.add(mono - r["mono_ns"])
        n_gap += bool(flags & GAP)
        n_late += bool(flags & LATE)
    if len(offsets) > 1:
        problems.append(f"CLOCK_MONOTONIC not spaced as recorded: {len(offsets)} different offsets")
    seen = {c0 for c0, *_ in chunks}
    for c0 in rows:
        if c0 + nfpc - 1 >= first and c0 <= last and c0 not in seen:
            if not all(f in lost_set or f < first or f > last for f in range(c0, c0 + nfpc)):
                problems.append(f"the chunk at frame {c0} has a row but the reader never saw it")
    if end is not None and (end[1] != "stopped" or not last <= end[0] < last + nfpc):
        problems.append(f"the replay ended at frame {end[0]}, {end[1]}; the recording ends at {last}")
    if problems:
        print(f"{dump}: {len(problems)} problem(s):")
        for p in problems[:25]:
            print("  " + p)
        return 1
    print(f"ok: frames {first}..{last} ({len(got)} read, {bits}-bit, {nch} ch), losses {losses}, "
          f"{len(chunks)} chunks ({n_gap} GAP, {n_late} LATE, {n_bound} with a bound), all flags, times, "
          f"bounds and channel masks as recorded")
    return 0


if __name__ == "__main__":
    sys.exit(main())
