"""A hostile peer for the network suite (tests/bridge/cases/rogue.sh): a real Zenoh session
(PyPI eclipse-zenoh, multicast scouting off) that connects to ENDPOINTS (comma-separated: the
mirror's listen endpoint, to reach it, and serve's, to read the real stream) and does what issue 20 measured breaking the mirror, while the real serve goes on:

  - sniffs one real chunk of SOURCE (its serve instance, epoch, frame, geometry);
  - a 96-byte chunk message asking for a 1 TiB geometry (64 ch x 2^20 frames x 4095 chunks);
  - a chunk of the real instance and epoch at frame ~2^62;
  - 10 chunks of 0x7fffffff samples at the next real frames, from another instance;
  - a forged `stopped` state and an `error` state full of terminal escapes (real instance);
  - 50 new epochs, each from a new instance;
  - garbage on the chunk key;
  - answers the clock query with 2.7e17 (and with 3-byte answers), beside the real serve;
  - answers the control query with an error full of terminal escapes.

Queryables stay up HOLD seconds. Prints a JSON summary line.

usage: rogue_peer.py ENDPOINTS NAMESPACE SOURCE HOLD
"""
import json
import random
import struct
import sys
import threading
import time

import zenoh

endpoints, ns, source, hold = sys.argv[1].split(","), sys.argv[2], sys.argv[3], float(sys.argv[4])
key = lambda leaf: f"{ns}/{source}/{leaf}"  # noqa: E731

HDR = struct.Struct("<8sHHIQQQQIHHIIQQQQ")  # bridge/src/wire.rs, 96 bytes
assert HDR.size == 96
MAGIC = b"BASSNET\0"
VERSION = 2  # wire format 2: flags as the port's chunk flags, samples planar
GAP = 1
MAX_FRAME_INDEX = 1 << 62
ESC = "\x1b]0;owned by rogue\x07\x1b[2J\x1b[31m\r\nFAKE LOG LINE"


def chunk(instance, epoch, first, frames, channels, rate, cop, flags=0, samples=None, seq=0):
    now = time.monotonic_ns()
    head = HDR.pack(MAGIC, VERSION, 96, flags, instance, epoch, seq, first, frames, channels, 1, rate, cop,
                    now, time.time_ns(), now, 0)
    if flags & GAP:
        return head
    if samples is None:
        samples = [0x7FFFFFFF] * (frames * channels)
    return head + struct.pack(f"<{len(samples)}i", *samples)


conf = zenoh.Config.from_json5(json.dumps({
    "mode": "peer",
    "connect": {"endpoints": endpoints},
    "listen": {"endpoints": []},
    "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
}))
summary = {"clock_answers": 0, "control_answers": 0}
with zenoh.open(conf) as s:
    deadline = time.monotonic() + 10
    while len(list(s.info.peers_zid())) < len(endpoints) and time.monotonic() < deadline:
        time.sleep(0.05)
    if len(list(s.info.peers_zid())) < len(endpoints):
        print("rogue_peer: not connected", file=sys.stderr)
        sys.exit(3)

    # The clock and control answers, beside the real serve's.
    def clock(q):
        summary["clock_answers"] += 1
        bogus = struct.pack("<Q", 270_000_000_000_000_000)
        q.reply(q.key_expr, bogus if summary["clock_answers"] % 4 else b"\x01\x02\x03")

    def control(q):
        summary["control_answers"] += 1
        body = {"version": "bass-control/2", "reply": "error", "kind": "internal", "message": ESC}
        q.reply(q.key_expr, json.dumps(body).encode())

    qc = s.declare_queryable(key("clock"), clock)
    qk = s.declare_queryable(key("control"), control)

    # A real chunk first: the rest aims at the stream the mirror follows.
    got = threading.Event()
    real = {}

    def on_chunk(sample):
        b = sample.payload.to_bytes()
        if len(b) >= 96 and b[:8] == MAGIC and not got.is_set():
            f = HDR.unpack(b[:96])
            real.update(instance=f[4], epoch=f[5], first=f[7], frames=f[8], channels=f[9], rate=f[11], cop=f[12])
            got.set()

    sub = s.declare_subscriber(key("chunks"), on_chunk)
    if not got.wait(10):
        print("rogue_peer: no real chunk seen", file=sys.stderr)
        sys.exit(4)
    sub.undeclare()
    inst, epoch, nf, ch, rate, cop = (real[k] for k in ("instance", "epoch", "frames", "channels", "rate", "cop"))
    nxt = real["first"] + 4 * nf
    put = lambda b: s.put(key("chunks"), b)  # noqa: E731

    # 1 TiB of geometry in 96 bytes.
    put(chunk(inst, epoch, nxt, 1 << 20, 64, rate, 4095, flags=GAP))
    # Frame ~2^62, the real instance and epoch.
    far = (MAX_FRAME_INDEX - 2 * nf) // nf * nf + 1
    put(chunk(inst, epoch, far, nf, ch, rate, cop))
    # 10 chunks of 0x7fffffff at the next real frames, from another instance.
    other = random.getrandbits(63) | 1
    for k in range(10):
        put(chunk(other, epoch, nxt + k * nf, nf, ch, rate, cop, seq=k))
        time.sleep(0.01)
    # Forged states with the real instance: stopped, and an error full of escapes.
    base = {"error_code": 0, "epoch": epoch, "channels": ch, "sample_rate": rate, "frames_per_chunk": nf,
            "chunks_on_port": cop, "last_frame_index": 0, "chunks_sent": 0, "chunks_dropped": 0,
            "instance": f"{inst:016x}", "zid": ""}
    s.put(key("state"), json.dumps(dict(base, state="stopped", message="")).encode())
    s.put(key("state"), json.dumps(dict(base, state="error", error_code=5, message=ESC)).encode())
    s.put(key("state"), json.dumps(dict(base, state="stopped", message="", instance="")).encode())
    # 50 new epochs, each from a new instance.
    for k in range(50):
        put(chunk(random.getrandbits(63) | 1, epoch + 1000 + k, 1, nf, ch, rate, cop, seq=k))
        time.sleep(0.01)
    # Garbage.
    for b in (b"", b"\x1b[2J" * 10, MAGIC + b"\x01\x00" + b"\xff" * 200):
        put(b)
    summary["sent"] = 1 + 1 + 10 + 3 + 50 + 3
    time.sleep(hold)
    qc.undeclare()
    qk.undeclare()
print(json.dumps(summary))
