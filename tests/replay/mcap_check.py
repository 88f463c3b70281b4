#!/usr/bin/env python3
"""Checks a `bass record --format mcap` bag directory with readers bass did not write:

- the PyPI `mcap` reader with `mcap-ros2-support`'s decoder (which builds its CDR decoder from
  the ros2msg schema in the file) decodes every message: the header's ros2 profile, each
  channel's cdr encoding and offered_qos_profiles, AudioInfo once (channels, rate, S32LE, wave),
  and per run of frames a bass_msgs/msg/ChunkInfo followed by an AudioDataStamped with the same
  sequence number and stamp, holding frames x channels S32LE samples;
- the frames tile the recording: each message starts where the one before ended plus its
  `lost_before`; the losses and GAP frames they describe are those the recorder reported
  (--recorder, its `--json` line) and the `bass` metadata record says;
- the samples are the signal's, for the recorded channels in their order: `--signal pattern`
  (every sample is pattern(frame, channel) of the sim device) or `--signal xrun` (GAP chunks
  are zeros; elsewhere each sample names its channel and the device frames run on by one
  inside a message);
- every ChunkInfo's timestamp bound and channel masks (the fields added at the message's end
  with port format 2.4) are the same in each message of a chunk, the masks name only the
  port's channels, and with `--expect-bound` every bound is known and under 1 s;
- `--wav REC.wav`: a WAV recording of the same port (with its sidecar) holds the same samples
  for every frame both have, and the same chunk rows (flags, both clocks, bound, masks);
- `rosbags` opens the directory as a rosbag2 bag and the .mcap file alone, and deserialises
  every message with the definitions stored in the file: the same samples and fields.

With `--ref OUT.wav` it writes what the messages say as a 32-bit WAV + sidecar (lost frames
as zeros), for tests/replay/compare.py to hold the replay against.
Prints one "ok" line, or the problems and exits 1.
"""
import argparse
import glob
import json
import os
import struct
import sys
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

GAP, DISCONTINUITY = 1, 2
AUDIO = "audio_common_msgs/msg/AudioDataStamped"
INFO = "audio_common_msgs/msg/AudioInfo"
CHUNK = "bass_msgs/msg/ChunkInfo"
UNKNOWN = 2**64 - 1  # ChunkInfo.bound_ns of a chunk without a known bound


def pattern(frame, channel):
    v = ((frame & 0x03FFFFFF) << 6) | (channel & 63)
    return v - (1 << 32) if v >= 1 << 31 else v


def samples_of(data, nch):
    n = len(data) // 4
    vals = struct.unpack(f"<{n}i", bytes(data))
    return [tuple(vals[i:i + nch]) for i in range(0, n, nch)]


def read_mcap(path, problems):
    """Every message through mcap + mcap-ros2-support: (facts, info, [(chunkinfo, frames)])."""
    runs, infos, pending, facts = [], [], None, None
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        if header.profile != "ros2":
            problems.append(f"MCAP profile {header.profile!r}, not ros2")
        summary = reader.get_summary()
        for c in summary.channels.values():
            schema = summary.schemas[c.schema_id]
            if c.message_encoding != "cdr" or schema.encoding != "ros2msg":
                problems.append(f"{c.topic}: encodings {c.message_encoding}/{schema.encoding}")
            if "offered_qos_profiles" not in c.metadata:
                problems.append(f"{c.topic}: no offered_qos_profiles")
        for m in reader.iter_metadata():
            if m.name == "bass":
                facts = json.loads(m.metadata["sidecar"])
        for schema, channel, msg, dec in reader.iter_decoded_messages():
            if schema.name == INFO:
                infos.append(dec)
            elif schema.name == CHUNK:
                if pending is not None:
                    problems.append(f"ChunkInfo {pending[0]} without its audio message")
                pending = (msg.sequence, dec)
            elif schema.name == AUDIO:
                if pending is None or pending[0] != msg.sequence:
                    problems.append(f"audio message {msg.sequence} without its ChunkInfo")
                    continue
                ci = pending[1]
                pending = None
                if (dec.header.stamp.sec, dec.header.stamp.nanosec) != (ci.header.stamp.sec, ci.header.stamp.nanosec):
                    problems.append(f"message {msg.sequence}: audio and ChunkInfo stamps differ")
                runs.append((ci, bytes(dec.audio.data), msg.sequence))
    return facts, infos, runs


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("bag")
    ap.add_argument("--signal", choices=["pattern", "xrun"], required=True)
    ap.add_argument("--recorder", help="the recorder's --json line")
    ap.add_argument("--wav", help="a WAV recording of the same port, with its sidecar")
    ap.add_argument("--ref", help="write the messages as WAV + sidecar here")
    ap.add_argument("--expect-loss", action="store_true", help="the recording must hold a loss")
    ap.add_argument("--expect-gap", action="store_true", help="it must hold GAP chunks")
    ap.add_argument("--expect-bound", action="store_true", help="every chunk's bound must be known (< 1 s)")
    a = ap.parse_args()
    problems = []
    files = glob.glob(os.path.join(a.bag, "*.mcap"))
    if len(files) != 1 or not os.path.exists(os.path.join(a.bag, "metadata.yaml")):
        print(f"{a.bag}: want one .mcap file and metadata.yaml, found {os.listdir(a.bag)}")
        return 1
    facts, infos, runs = read_mcap(files[0], problems)
    if facts is None:
        print(f"{files[0]}: no bass metadata record")
        return 1
    acq, rec = facts["acquisition"], facts["recording"]
    chans = rec["channels"]
    nch, nfpc = len(chans), acq["frames_per_chunk"]
    if len(infos) != 1:
        problems.append(f"{len(infos)} AudioInfo messages, want 1")
    else:
        i = infos[0]
        got = (i.channels, i.sample_rate, i.sample_format, i.coding_format, i.bitrate)
        want = (nch, acq["sample_rate"], "S32LE", "wave", acq["sample_rate"] * nch * 32)
        if got != want:
            problems.append(f"AudioInfo {got}, want {want}")
    # The frames, the losses, the rows.
    frames, losses, rows = {}, [], {}
    nxt = rec["first_frame"]
    gap_frames = 0
    for ci, data, seq in runs:
        if ci.first_frame != nxt + ci.lost_before:
            problems.append(f"message {seq}: first frame {ci.first_frame}, want {nxt} + lost {ci.lost_before}")
        if ci.lost_before:
            losses.append({"first_frame": nxt, "frames": ci.lost_before})
        if len(data) != ci.frames * nch * 4:
            problems.append(f"message {seq}: {len(data)} bytes for {ci.frames} frames of {nch} channels")
        fr = samples_of(data, nch)
        chunk = (ci.first_frame - 1) // nfpc * nfpc + 1
        if ci.chunk_first_frame:
            if ci.chunk_first_frame != chunk or ci.chunk_frames != nfpc:
                problems.append(f"message {seq}: chunk {ci.chunk_first_frame}/{ci.chunk_frames}, want {chunk}/{nfpc}")
            row = {"first_frame": chunk, "frames": nfpc, "mono_ns": ci.monotonic_ns,
                   "realtime_ns": ci.realtime_ns, "flags": ci.flags}
            # The sidecar's form of the bound (absent: not known) and masks (absent: 0).
            for k, v in (("bound_ns", ci.bound_ns), ("missing_channels", ci.missing_channels),
                         ("unaligned_channels", ci.unaligned_channels)):
                if v != {"bound_ns": UNKNOWN}.get(k, 0):
                    row[k] = v
            if rows.get(chunk, row) != row:
                problems.append(f"message {seq}: chunk {chunk} is {row}; a message before it said {rows[chunk]}")
            if a.expect_bound and not ci.bound_ns < 10**9:
                problems.append(f"message {seq}: chunk {chunk}'s bound_ns {ci.bound_ns}, not a bound under 1 s")
            if (ci.missing_channels | ci.unaligned_channels) >> acq["channels"]:
                problems.append(f"message {seq}: masks {ci.missing_channels:#x}, {ci.unaligned_channels:#x} "
                                f"name channels the port ({acq['channels']}) does not have")
            rows[chunk] = row
        gap = bool(ci.flags & GAP)
        gap_frames += len(fr) if gap else 0
        for k, s in enumerate(fr):
            f = ci.first_frame + k
            frames[f] = s
            if gap:
                if any(s):
                    problems.append(f"frame {f} of a GAP chunk is {s}, not zeros")
            elif a.signal == "pattern" and s != tuple(pattern(f, c) for c in chans):
                problems.append(f"frame {f}: {s}, the pattern is {tuple(pattern(f, c) for c in chans)}")
            elif a.signal == "xrun" and s != tuple(pattern(f, c) for c in chans):
                if any(s) or not ci.flags & DISCONTINUITY:
                    problems.append(f"frame {f}: {s}, neither the pattern nor the zeros of a DISCONTINUITY chunk")
        nxt = ci.first_frame + ci.frames
    end = rec["first_frame"] + rec["frames"]
    if nxt < end:
        losses.append({"first_frame": nxt, "frames": end - nxt})
    lost = sum(x["frames"] for x in losses)
    if losses != facts["losses"]:
        problems.append(f"the messages' losses {losses}; the bass metadata says {facts['losses']}")
    if len(frames) + lost != rec["frames"]:
        problems.append(f"{len(frames)} frames + {lost} lost; the recording holds {rec['frames']}")
    if gap_frames != rec["gap_frames"]:
        problems.append(f"{gap_frames} GAP frames in messages; the metadata says {rec['gap_frames']}")
    if a.recorder:
        r = json.loads(open(a.recorder).read())
        start = runs[0][0].first_frame - runs[0][0].lost_before if runs else None
        for k in ("first_frame", "frames", "lost_frames", "gap_frames"):
            mine = {"first_frame": start, "frames": len(frames) + lost,
                    "lost_frames": lost, "gap_frames": gap_frames}[k]
            if r[k] != mine:
                problems.append(f"the recorder reported {k} {r[k]}; the messages say {mine}")
    if a.expect_loss and not lost:
        problems.append("no loss in the recording (nothing tested)")
    if a.expect_gap and not gap_frames:
        problems.append("no GAP chunk in the recording (nothing tested)")
    if a.wav:
        wav_side = json.load(open(a.wav + ".json"))
        wav_frames = read_wav32(a.wav)
        wlost = {f for x in wav_side["losses"] for f in range(x["first_frame"], x["first_frame"] + x["frames"])}
        w0 = wav_side["recording"]["first_frame"]
        both = [f for f in frames if w0 <= f < w0 + len(wav_frames) and f not in wlost]
        diff = [f for f in both if frames[f] != wav_frames[f - w0]]
        if not both or diff:
            problems.append(f"{len(both)} frames in both recordings; these differ: {diff[:5]}")
        wrows = {r["first_frame"]: r for r in wav_side["chunks"]}
        rdiff = [c for c in rows if c in wrows and rows[c] != wrows[c]]
        if rdiff or not set(rows) & set(wrows):
            problems.append(f"chunk rows differ from the WAV's sidecar at {rdiff[:5]}")
    # rosbags: the bag directory and the file alone, every message.
    try:
        n_bag = check_rosbags(Path(a.bag), runs, nch, problems)
        n_file = check_rosbags(Path(files[0]), runs, nch, problems)
    except Exception as e:  # a reader's refusal is a finding, not a crash of the checker
        problems.append(f"rosbags: {type(e).__name__}: {e}")
        n_bag = n_file = 0
    if a.ref:
        write_ref(a.ref, facts, frames, losses, rows, nch)
    if problems:
        print(f"{a.bag}: {len(problems)} problem(s):")
        for p in problems[:25]:
            print("  " + p)
        return 1
    print(f"ok: {len(runs)} audio messages decoded by mcap-ros2-support, frames {rec['first_frame']}.."
          f"{end - 1} ({len(frames)} with samples, {a.signal} signal), {lost} lost in {len(losses)} run(s), "
          f"{gap_frames} GAP, {sum('bound_ns' in r for r in rows.values())} of {len(rows)} chunk rows with a "
          f"timestamp bound (at most {max([r.get('bound_ns', 0) for r in rows.values()] or [0])} ns); rosbags deserialised {n_bag} messages from the bag directory and {n_file} "
          f"from the .mcap file")
    return 0


def check_rosbags(path, runs, nch, problems):
    n = 0
    audio = []
    chunks = []
    with AnyReader([path]) as r:
        for con, _ts, raw in r.messages():
            m = r.deserialize(raw, con.msgtype)
            n += 1
            if con.msgtype == AUDIO:
                audio.append(bytes(m.audio.data))
            elif con.msgtype == CHUNK:
                chunks.append((m.first_frame, m.frames, m.flags, m.lost_before, m.realtime_ns, m.bound_ns,
                               m.missing_channels, m.unaligned_channels))
    if audio != [d for _, d, _ in runs]:
        problems.append(f"rosbags ({path.name}): {len(audio)} audio messages, not the same as mcap-ros2-support's")
    want = [(c.first_frame, c.frames, c.flags, c.lost_before, c.realtime_ns, c.bound_ns, c.missing_channels,
             c.unaligned_channels) for c, _, _ in runs]
    if chunks != want:
        problems.append(f"rosbags ({path.name}): ChunkInfo fields differ from mcap-ros2-support's")
    return n


def read_wav32(path):
    """Frames of a WAV of bass record (any bits), left-justified to 32 bits."""
    data = open(path, "rb").read()
    pos, fmt, body = 12, None, None
    while pos + 8 <= len(data):
        cid, size = data[pos:pos + 4], struct.unpack_from("<I", data, pos + 4)[0]
        if cid == b"fmt ":
            fmt = data[pos + 8:pos + 8 + size]
        elif cid == b"data":
            body = data[pos + 8:pos + 8 + size]
            break
        pos += 8 + size + (size & 1)
    _tag, nch, _rate, _bps, align, bits = struct.unpack_from("<HHIIHH", fmt)
    width = bits // 8
    out = []
    for off in range(0, len(body) - align + 1, align):
        row = []
        for c in range(nch):
            v = int.from_bytes(body[off + c * width:off + (c + 1) * width], "little", signed=True)
            v = (v << (32 - bits)) & 0xFFFFFFFF
            row.append(v - (1 << 32) if v >= 1 << 31 else v)
        out.append(tuple(row))
    return out


def write_ref(path, facts, frames, losses, rows, nch):
    acq, rec = facts["acquisition"], facts["recording"]
    first, total = rec["first_frame"], rec["frames"]
    body = bytearray()
    for f in range(first, first + total):
        body += struct.pack(f"<{nch}i", *frames.get(f, (0,) * nch))
    rate = acq["sample_rate"]
    hdr = b"RIFF" + struct.pack("<I", 36 + len(body)) + b"WAVE"
    hdr += b"fmt " + struct.pack("<IHHIIHH", 16, 1, nch, rate, rate * nch * 4, nch * 4, 32)
    hdr += b"data" + struct.pack("<I", len(body))
    open(path, "wb").write(hdr + body)
    side = {"acquisition": acq, "recording": dict(rec, file=path, bits=32, lost_frames=sum(x["frames"] for x in losses)),
            "losses": losses, "chunks": [rows[c] for c in sorted(rows)]}
    open(path + ".json", "w").write(json.dumps(side))


if __name__ == "__main__":
    sys.exit(main())
