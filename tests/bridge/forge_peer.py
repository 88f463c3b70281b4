"""A hostile but authenticated peer for the network suite: a real Zenoh session (PyPI
eclipse-zenoh) that connects to ENDPOINT as USER/PASSWORD and puts COUNT messages on KEY.
The messages are not bass chunk messages, so a mirror that receives them counts them in
`invalid_messages`: the count tells whether they got through. Multicast scouting off.

usage: forge_peer.py ENDPOINT USER PASSWORD KEY COUNT
"""
import json
import sys
import time

import zenoh

endpoint, user, password, key, count = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5])
conf = zenoh.Config.from_json5(json.dumps({
    "mode": "peer",
    "connect": {"endpoints": [endpoint]},
    "listen": {"endpoints": []},
    "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
    "transport": {"auth": {"usrpwd": {"user": user, "password": password}}},
}))
with zenoh.open(conf) as s:
    deadline = time.monotonic() + 10
    while not list(s.info.peers_zid()) and time.monotonic() < deadline:
        time.sleep(0.05)
    if not list(s.info.peers_zid()):
        print("forge_peer: not connected", file=sys.stderr)
        sys.exit(3)
    for _ in range(count):
        s.put(key, b"forged by " + user.encode())
        time.sleep(0.02)
    time.sleep(0.5)
print(f"forge_peer: {count} messages put on {key} as {user}")
