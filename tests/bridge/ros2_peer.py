"""ROS 2 peers of `serve --ros2` for tests/bridge/cases/ros2_acl.sh and scripts/bench-ros2-flood.sh:
real eclipse-zenoh sessions (PyPI) in client mode (a router forwards between its clients, not
between peers, which it expects to meet directly; ROS2_PEER_MODE=peer makes them peers), logged
in with a bass pair password, on the key
expressions rmw_zenoh's layout gives bass's default topics (/bass/<broker>/audio and
audio_info, domain 0), the CDR payloads made and read by rosbags as a ROS node would.

  consume ENDPOINT USER PASSWORD BROKER SECONDS READY_FILE
      a ROS consumer of the audio topic: writes READY_FILE once subscribed, reads for SECONDS,
      and judges every decoded AudioDataStamped: real (its samples are bass's test pattern for
      consecutive frames, 2 channels) or not; prints {"audio_good", "audio_bad", "contiguous",
      "frames", "audio_info", "other"} (audio_info: the latched AudioInfo a late subscriber got;
      other: messages on the forger's own topic /ws2/chatter)
  forge ENDPOINT USER PASSWORD BROKER COUNT
      puts COUNT well-formed AudioDataStamped messages (480 frames of 0x41414141, now as stamp,
      a 33-byte rmw_zenoh attachment) on the audio key, and as many std_msgs/String on its own
      topic /ws2/chatter (an ordinary ROS node's); prints {"put": N}
  flood ENDPOINT USER PASSWORD BROKER SECONDS
      sends history queries on the audio_info topic (as a TRANSIENT_LOCAL subscriber's, without
      waiting for answers) as fast as it can for SECONDS; prints {"queries", "replies"}
"""
import json
import os
import sys
import threading
import time

import numpy as np
import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

DEFS = {
    "audio_common_msgs/msg/AudioData": "uint8[] data\n",
    "audio_common_msgs/msg/AudioDataStamped": "std_msgs/Header header\naudio_common_msgs/AudioData audio\n",
    "audio_common_msgs/msg/AudioInfo": (
        "uint8 channels\nuint32 sample_rate\nstring sample_format\nuint32 bitrate\nstring coding_format\n"
    ),
}
store = get_typestore(Stores.ROS2_JAZZY)
for name, text in DEFS.items():
    store.register(get_types_from_msg(text, name))
AUDIO, INFO = "audio_common_msgs/msg/AudioDataStamped", "audio_common_msgs/msg/AudioInfo"
STRING, CHATTER = "std_msgs/msg/String", "/ws2/chatter"
CHANNELS = 2


def key(ros_type, topic):
    pkg, sub, name = ros_type.split("/")
    return f"0/{topic.strip('/')}/{pkg}::{sub}::dds_::{name}_/{store.hash_rihs01(ros_type)}"


def session(endpoint, user, password):
    conf = {
        "mode": os.environ.get("ROS2_PEER_MODE", "client"),
        "connect": {"endpoints": [endpoint]},
        "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"user": user, "password": password}}},
    }
    s = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
    deadline = time.monotonic() + 10
    while not list(s.info.peers_zid()) + list(s.info.routers_zid()):
        if time.monotonic() > deadline:
            print(f"ros2_peer: {user} not admitted at {endpoint}", file=sys.stderr)
            sys.exit(3)
        time.sleep(0.05)
    return s


def pattern(first, frames):
    f = np.arange(first, first + frames, dtype=np.uint64)
    return [(((f & np.uint64(0x3FFFFFF)) << np.uint64(6)) | np.uint64(ch)).astype(np.uint32).view(np.int32)
            for ch in range(CHANNELS)]


def real_first_frame(data):
    """The first frame of a message that is bass's pattern, or None."""
    if data.size == 0 or data.size % CHANNELS:
        return None
    frames = data.size // CHANNELS
    first = (int(data[0].view(np.uint32)) >> 6) & 0x3FFFFFF
    want = pattern(first, frames)
    ok = all(np.array_equal(data[ch::CHANNELS], want[ch]) for ch in range(CHANNELS))
    return first if ok else None


def consume(endpoint, user, pw, broker, seconds, ready):
    s = session(endpoint, user, pw)
    got = []
    sub = s.declare_subscriber(key(AUDIO, f"/bass/{broker}/audio"), lambda x: got.append(x.payload.to_bytes()))
    infos = []
    info_sub = zenoh.ext.declare_advanced_subscriber(
        s, key(INFO, f"/bass/{broker}/audio_info"), lambda x: infos.append(x.payload.to_bytes()),
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1))
    other = []
    other_sub = s.declare_subscriber(key(STRING, CHATTER), lambda x: other.append(1))
    time.sleep(0.5)  # the declarations reach the router
    open(ready, "w").close()
    time.sleep(seconds)
    sub.undeclare(); info_sub.undeclare(); other_sub.undeclare()
    good, bad, frames, contiguous, prev = 0, 0, 0, True, None
    for p in got[:]:
        m = store.deserialize_cdr(p, AUDIO)
        data = np.frombuffer(bytes(m.audio.data), dtype="<i4")
        first = real_first_frame(data)
        if first is None:
            bad += 1
            continue
        good += 1
        n = data.size // CHANNELS
        frames += n
        if prev is not None and first != prev:
            contiguous = False
        prev = first + n
    info = None
    if infos:
        i = store.deserialize_cdr(infos[-1], INFO)
        info = {"channels": int(i.channels), "rate": int(i.sample_rate), "format": i.sample_format}
    print(json.dumps({"audio_good": good, "audio_bad": bad, "contiguous": contiguous, "frames": frames,
                      "audio_info": info, "other": len(other)}))
    s.close()


def forge(endpoint, user, pw, broker, count):
    s = session(endpoint, user, pw)
    time.sleep(0.5)  # the router's subscriptions reach this session
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    AudioData, Stamped = store.types["audio_common_msgs/msg/AudioData"], store.types[AUDIO]
    pub = s.declare_publisher(key(AUDIO, f"/bass/{broker}/audio"))
    chatter = s.declare_publisher(key(STRING, CHATTER))
    String = store.types[STRING]
    gid = os.urandom(16)
    samples = np.full(480 * CHANNELS, 0x41414141, dtype="<i4").view(np.uint8)
    for i in range(count):
        now = time.time_ns()
        m = Stamped(header=Header(stamp=Time(sec=now // 10**9, nanosec=now % 10**9), frame_id=""),
                    audio=AudioData(data=samples))
        att = (i + 1).to_bytes(8, "little") + now.to_bytes(8, "little") + bytes([16]) + gid
        pub.put(bytes(store.serialize_cdr(m, AUDIO)), attachment=att)
        chatter.put(bytes(store.serialize_cdr(String(data=f"hello {i}"), STRING)), attachment=att)
        time.sleep(0.01)
    time.sleep(0.5)
    print(json.dumps({"put": count}))
    s.close()


def flood(endpoint, user, pw, broker, seconds):
    s = session(endpoint, user, pw)
    k = key(INFO, f"/bass/{broker}/audio_info") + "/@adv/**"
    replies, n = [0], 0
    lock = threading.Lock()

    def on_reply(r):
        if r.ok is not None:
            with lock:
                replies[0] += 1

    end = time.monotonic() + seconds
    while time.monotonic() < end:
        s.get(k + "?_max=1", on_reply, accept_replies=zenoh.ReplyKeyExpr.ANY)
        n += 1
    time.sleep(0.5)
    print(json.dumps({"queries": n, "replies": replies[0]}))
    s.close()


def main():
    mode, a = sys.argv[1], sys.argv[2:]
    if mode == "consume":
        consume(a[0], a[1], a[2], a[3], float(a[4]), a[5])
    elif mode == "forge":
        forge(a[0], a[1], a[2], a[3], int(a[4]))
    elif mode == "flood":
        flood(a[0], a[1], a[2], a[3], float(a[4]))


main()
