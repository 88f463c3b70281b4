"""Strangers and trusted colleagues trying to get in (tests/bridge/cases/security.sh): real Zenoh
sessions (PyPI eclipse-zenoh, multicast scouting and gossip off), one per identity tried.

  lines ENDPOINT FILE...      every line of every FILE as Zenoh's dictionary parser would read
                              it (split at the first ':'), and at the first space, and the
                              comment line every version-1 credentials file began with: prints
                              {"tried": N, "admitted": [...]} (admitted: the ones given a session)
  pairs ENDPOINT USER PASSWORD [USER PASSWORD]...
                              the same for the pairs given
  try ENDPOINT USER PASSWORD  exit 0 if a session comes up, 3 if not
  forge PUT_EP PUT_PW SNIFF_EP SNIFF_PW USER NS SOURCE COUNT HOLD
                              as USER: sniffs one real chunk of SOURCE through SNIFF_EP, then
                              through PUT_EP puts COUNT well-formed chunk messages of the real
                              instance and epoch at the next frames, full of 0x41414141, and
                              declares a liveliness token of the real instance; holds HOLD s;
                              prints {"sniffed": bool, "put": N}

All attempts of one call run at once (a thread each), each given 3 s to be admitted.
"""
import json
import struct
import sys
import threading
import time

import zenoh

HDR = struct.Struct("<8sHHIQQQQIHHIIQQQQ")  # bridge/src/wire.rs, 96 bytes
OLD_COMMENT = "# bass-bridge credentials: first line = this machine; all lines = accepted"


def session(endpoints, user, password):
    conf = {
        "mode": "peer",
        "connect": {"endpoints": endpoints},
        "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
    }
    if user is not None:
        conf["transport"] = {"auth": {"usrpwd": {"user": user, "password": password}}}
    return zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))


def admitted(s, n=1, wait=2.0):
    deadline = time.monotonic() + wait
    while len(list(s.info.peers_zid())) < n and time.monotonic() < deadline:
        time.sleep(0.05)
    return len(list(s.info.peers_zid())) >= n


def candidates(files):
    out = [tuple(OLD_COMMENT.split(":", 1))]
    for f in files:
        for line in open(f):
            line = line.strip()
            if not line:
                continue
            for sep in (":", " "):
                if sep in line:
                    u, p = line.split(sep, 1)
                    if u.strip() and p.strip():
                        out.append((u.strip(), p.strip()))
    return list(dict.fromkeys(out))


def attempt_all(endpoint, pairs):
    got = []

    def one(user, password):
        with session([endpoint], user, password) as s:
            if admitted(s, wait=3.0):
                got.append(user)

    threads = [threading.Thread(target=one, args=p) for p in pairs]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    print(json.dumps({"tried": len(pairs), "admitted": sorted(got)}))


def main():
    mode = sys.argv[1]
    if mode == "lines":
        attempt_all(sys.argv[2], candidates(sys.argv[3:]))
    elif mode == "pairs":
        a = sys.argv[3:]
        attempt_all(sys.argv[2], list(zip(a[0::2], a[1::2])))
    elif mode == "try":
        with session([sys.argv[2]], sys.argv[3], sys.argv[4]) as s:
            sys.exit(0 if admitted(s, wait=4) else 3)
    elif mode == "forge":
        put_ep, put_pw, sniff_ep, sniff_pw, user, ns, source = sys.argv[2:9]
        count, hold = int(sys.argv[9]), float(sys.argv[10])
        key = lambda leaf: f"{ns}/{source}/{leaf}"  # noqa: E731
        with session([sniff_ep], user, sniff_pw) as sn:
            if not admitted(sn, wait=10):
                print("stranger: not admitted where it sniffs", file=sys.stderr)
                sys.exit(3)
            real, got = {}, threading.Event()

            def on_chunk(sample):
                b = sample.payload.to_bytes()
                if len(b) >= 96 and b[:8] == b"BASSNET\0" and not got.is_set():
                    real["h"] = HDR.unpack(b[:96])
                    got.set()

            sub = sn.declare_subscriber(key("chunks"), on_chunk)
            sniffed = got.wait(10)
            sub.undeclare()
        put = 0
        with session([put_ep], user, put_pw) as s:
            if not admitted(s, wait=10):
                print("stranger: not admitted where it puts", file=sys.stderr)
                sys.exit(3)
            if sniffed:
                h = list(real["h"])
                frames, channels = h[8], h[9]
                token = s.liveliness().declare_token(key(f"alive/{h[4]:016x}"))
                first = h[7] + 8 * frames
                for i in range(count):
                    now = time.monotonic_ns()
                    h[6] += 1; h[7] = first + i * frames; h[13] = now; h[14] = time.time_ns(); h[15] = now
                    s.put(key("chunks"), HDR.pack(*h) + struct.pack(f"<{frames * channels}i", *([0x41414141] * (frames * channels))))
                    put += 1
                    time.sleep(0.01)
                time.sleep(hold)
                token.undeclare()
        print(json.dumps({"sniffed": sniffed, "put": put}))


main()
