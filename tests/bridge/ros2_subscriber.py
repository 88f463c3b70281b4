"""A ROS 2 subscriber without ROS: checks `bass-bridge serve --ros2` as rmw_zenoh would see it.

Everything is built here from rmw_zenoh's documented layout (ros2/rmw_zenoh docs/design.md,
Jazzy) and the upstream message definitions, not taken from bass's output:
- the type hashes: rosbags (PyPI) computes RIHS01 from the definitions below;
- the key expressions `<domain>/<topic>/<pkg>::msg::dds_::<Type>_/<hash>` and the liveliness
  tokens `@ros2_lv/<domain>/<zid>/<nid>/<eid>/<NN|MP>/%/<ns>/<node>[/<topic>/<type>/<hash>/<qos>]`;
- the payloads: rosbags deserialises each CDR message with the definitions below.

Then it subscribes with eclipse-zenoh (PyPI) on the exact keys and checks every message:
samples against bass's test pattern, stamps, the companion topic's frame indices (contiguous,
no loss), the 33-byte attachments (consecutive sequence numbers, one GID per publisher), and
the latched AudioInfo through a history query (TRANSIENT_LOCAL).

  ros2_subscriber.py ENDPOINT MODE ZID DOMAIN NODE TOPIC SECONDS CHANNELS RATE
prints one JSON line; exit 0 when every check held.
"""
import json
import re
import sys
import time

import numpy as np
import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

ENDPOINT, MODE, ZID, DOMAIN, NODE, TOPIC = sys.argv[1:7]
SECONDS, CHANNELS, RATE = float(sys.argv[7]), int(sys.argv[8]), int(sys.argv[9])

# Upstream definitions: audio_common_msgs (ROS 2 branch of ros-drivers/audio_common), and
# bass's own companion message (the ROS package ros2/bass_msgs); std_msgs/Header and builtin_interfaces/Time
# come with rosbags' Jazzy store.
DEFS = {
    "audio_common_msgs/msg/AudioData": "uint8[] data\n",
    "audio_common_msgs/msg/AudioDataStamped": "std_msgs/Header header\naudio_common_msgs/AudioData audio\n",
    "audio_common_msgs/msg/AudioInfo": (
        "uint8 channels\nuint32 sample_rate\nstring sample_format\nuint32 bitrate\nstring coding_format\n"
    ),
    # The file a ROS user builds (ros2/bass_msgs, colcon): its hash must be the one bass
    # puts on its key expression.
    "bass_msgs/msg/ChunkInfo": open("ros2/bass_msgs/msg/ChunkInfo.msg").read(),
}
store = get_typestore(Stores.ROS2_JAZZY)
types = {}
for name, text in DEFS.items():
    types.update(get_types_from_msg(text, name))
store.register(types)

AUDIO, INFO, CHUNK = "audio_common_msgs/msg/AudioDataStamped", "audio_common_msgs/msg/AudioInfo", "bass_msgs/msg/ChunkInfo"
parent = TOPIC.rsplit("/", 1)[0]
TOPICS = {AUDIO: TOPIC, INFO: TOPIC + "_info", CHUNK: parent + "/chunk_info"}
QOS = {AUDIO: "::,10:,:,:,,", INFO: ":1:,1:,:,:,,", CHUNK: "::,10:,:,:,,"}


def dds(ros_type):
    pkg, sub, name = ros_type.split("/")
    return f"{pkg}::{sub}::dds_::{name}_"


HASH = {t: store.hash_rihs01(t) for t in TOPICS}
KEY = {t: f"{DOMAIN}/{TOPICS[t].strip('/')}/{dds(t)}/{HASH[t]}" for t in TOPICS}
failures = []


def check(cond, what):
    if not cond:
        failures.append(what)
    return cond


conf = zenoh.Config()
conf.insert_json5("mode", json.dumps(MODE))
conf.insert_json5("connect/endpoints", json.dumps([ENDPOINT]))
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("scouting/gossip/enabled", "false")
session = zenoh.open(conf)

# The graph, as rmw_zenoh's graph cache reads it (waiting for the session to come up).
tokens = []
deadline = time.time() + 10
while time.time() < deadline and len(tokens) < 4:
    tokens = [str(r.ok.key_expr) for r in session.liveliness().get(f"@ros2_lv/{DOMAIN}/**", timeout=2) if r.ok]
    time.sleep(0.2)
node_re = re.compile(rf"^@ros2_lv/{DOMAIN}/([0-9a-f]+)/(\d+)/(\d+)/NN/%/%/{NODE}$")
nodes = [m for m in map(node_re.match, tokens) if m]
check(len(nodes) == 1, f"one node token for {NODE}: {tokens}")
nid = None
if nodes:
    zid, nid, eid = nodes[0].groups()
    check(zid == ZID, f"node token's session id {zid} is serve's Zenoh id {ZID}")
    check(nid == eid, f"a node token's node id and entity id are one: {nid} {eid}")
eids = set()
for t in TOPICS:
    want = re.compile(
        rf"^@ros2_lv/{DOMAIN}/{ZID}/{nid}/(\d+)/MP/%/%/{NODE}/{re.escape(TOPICS[t].replace('/', '%'))}/"
        rf"{re.escape(dds(t))}/{HASH[t]}/{re.escape(QOS[t])}$"
    )
    found = [m for m in map(want.match, tokens) if m]
    if check(len(found) == 1, f"one publisher token for {TOPICS[t]} ({dds(t)}, {HASH[t]}, qos {QOS[t]}): {tokens}"):
        eids.add(found[0].group(1))
check(len(eids) == 3 and nid not in eids, f"entity ids distinct: {eids} node {nid}")

# The latched AudioInfo: a late subscriber gets it from the publisher's cache.
infos = []
info_sub = zenoh.ext.declare_advanced_subscriber(
    session, KEY[INFO], lambda s: infos.append(s),
    history=zenoh.ext.HistoryConfig(detect_late_publishers=True))
audio, chunks = [], []
sub_a = session.declare_subscriber(KEY[AUDIO], lambda s: audio.append((s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else b"")))
sub_c = session.declare_subscriber(KEY[CHUNK], lambda s: chunks.append((s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else b"")))
want = int(SECONDS * RATE / 480)
deadline = time.time() + SECONDS + 15
while time.time() < deadline and (len(audio) < want or len(chunks) < want or not infos):
    time.sleep(0.05)
sub_a.undeclare(); sub_c.undeclare()
audio, chunks = audio[:], chunks[:]
now_ns = time.time_ns()
check(len(audio) >= want and len(chunks) >= want, f"{len(audio)} audio and {len(chunks)} chunk_info messages in time (want {want})")


def attachment(a, what):
    if not check(len(a) == 33 and a[16] == 16, f"{what}: attachment of 33 bytes with GID length 16: {a.hex()}"):
        return None, None, None
    return int.from_bytes(a[:8], "little", signed=True), int.from_bytes(a[8:16], "little", signed=True), a[17:]


def stamp_ns(h):
    return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


# Pair each audio message with its ChunkInfo by stamp (both topics carry the same header).
info_by_stamp = {}
seqs = {AUDIO: [], CHUNK: []}
gids = {AUDIO: set(), CHUNK: set()}
for payload, att in chunks:
    m = store.deserialize_cdr(payload, CHUNK)
    info_by_stamp[stamp_ns(m.header)] = m
    seq, ts, gid = attachment(att, "chunk_info")
    if seq is not None:
        seqs[CHUNK].append(seq); gids[CHUNK].add(gid)
        check(abs(ts - now_ns) < 60e9, f"chunk_info source timestamp {ts} near now {now_ns}")
samples_checked = 0
prev = None
decoded = [(store.deserialize_cdr(p, AUDIO), a) for p, a in audio]
# The two subscriptions start and stop a message apart: an audio message at either end may
# miss its ChunkInfo; one in between may not.
while decoded and stamp_ns(decoded[-1][0].header) not in info_by_stamp:
    decoded.pop()
while decoded and stamp_ns(decoded[0][0].header) not in info_by_stamp:
    decoded.pop(0)
check(len(decoded) >= want - 2, f"{len(decoded)} audio messages paired with their ChunkInfo")
for m, att in decoded:
    seq, ts, gid = attachment(att, "audio")
    if seq is not None:
        seqs[AUDIO].append(seq); gids[AUDIO].add(gid)
    st = stamp_ns(m.header)
    check(abs(st - now_ns) < 60e9, f"header.stamp {st} within a minute of now {now_ns}")
    c = info_by_stamp.get(st)
    if not check(c is not None, f"a chunk_info with the audio message's stamp {st}"):
        continue
    data = np.frombuffer(bytes(m.audio.data), dtype="<i4")
    check(data.size == c.frames * CHANNELS, f"{data.size} samples for {c.frames} frames x {CHANNELS}")
    f = np.arange(c.first_frame, c.first_frame + c.frames, dtype=np.uint64)
    right = data.size == c.frames * CHANNELS
    for ch in range(CHANNELS):
        exp = (((f & np.uint64(0x3FFFFFF)) << np.uint64(6)) | np.uint64(ch)).astype(np.uint32).view(np.int32)
        right &= check(np.array_equal(data[ch::CHANNELS], exp), f"samples of frames {c.first_frame}.. channel {ch} are the pattern")
    samples_checked += c.frames if right else 0
    check(c.realtime_ns == st and c.lost_before == 0 and c.flags & 1 == 0 and c.chunk_first_frame == c.first_frame,
          f"chunk_info consistent, no loss: {c}")
    # bassd's capture bounds every chunk's stamp (docs/time.md: under a second, never unknown,
    # 2^64-1); a sim device has no missing or unaligned channel.
    check(c.bound_ns < 10**9 and c.missing_channels == 0 == c.unaligned_channels,
          f"chunk_info carries the port row's bound and masks: {c.bound_ns}, {c.missing_channels}, {c.unaligned_channels}")
    if prev is not None:
        check(c.epoch == prev.epoch and c.first_frame == prev.first_frame + prev.frames,
              f"frame indices contiguous: {prev.first_frame}+{prev.frames} then {c.first_frame}")
        check(st > stamp_ns(prev.header), "stamps increase")
    prev = c
for t, s in seqs.items():
    check(len(s) > 1 and all(b == a + 1 for a, b in zip(s, s[1:])), f"{t}: sequence numbers consecutive: {s[:3]}..{s[-3:]}")
    check(len(gids[t]) == 1, f"{t}: one GID for all messages: {gids[t]}")
check(gids[AUDIO] != gids[CHUNK], "each publisher its own GID")
info = None
if check(len(infos) >= 1, "the latched AudioInfo arrived through the history query"):
    s = infos[-1]
    info = store.deserialize_cdr(s.payload.to_bytes(), INFO)
    check((info.channels, info.sample_rate, info.sample_format, info.bitrate, info.coding_format)
          == (CHANNELS, RATE, "S32LE", RATE * CHANNELS * 32, "wave"), f"AudioInfo {info}")
    attachment(s.attachment.to_bytes() if s.attachment else b"", "audio_info")
session.close()
print(json.dumps({
    "audio": len(audio), "chunk_info": len(chunks), "samples_checked_frames": samples_checked,
    "last_first_frame": int(prev.first_frame) if prev else None, "tokens": len(tokens),
    "hash_audio": HASH[AUDIO], "key_audio": KEY[AUDIO],
    "audio_info": info and {"channels": int(info.channels), "rate": int(info.sample_rate), "format": info.sample_format},
    "failures": failures[:8],
}))
sys.exit(1 if failures else 0)
