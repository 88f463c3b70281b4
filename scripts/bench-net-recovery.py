#!/usr/bin/env python3
"""Recovery time after a link outage (scripts/bench-network.sh; not a test).

usage: bench-net-recovery.py SRC_DIR SRC_NAME REP_DIR REP_NAME TIMEOUT_S -- LINK-UP COMMAND...

Runs the LINK-UP command (e.g. `ip -n NS link set vA up`), then polls every 5 ms, for at most
TIMEOUT_S seconds, the source port (broker SRC_NAME in runtime directory SRC_DIR) and the
replica port (REP_NAME in REP_DIR), both through the C library (python/bass; the shared
memory is one file system whatever the network namespaces). Prints one JSON line:

- `moved_s`: seconds from the end of the link-up command until the replica's
  last_frame_index first moved (null: not within TIMEOUT_S);
- `live_s`: until the replica held the frame that was the source's newest at link-up (it
  carries audio captured after the outage; null: not within TIMEOUT_S);
- `source_lfi_at_up`, `replica_lfi_at_up`, `replica_lfi_end`.

Each poll opens the port afresh (a mirror may replace the replica with a new port).
"""

import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
import bass  # noqa: E402  (the source tree's package; BASS_LIB or target/release)


def lfi(runtime_dir, name):
    """The newest frame of port `name` in `runtime_dir`, or None (no port yet)."""
    os.environ["BASS_RUNTIME_DIR"] = runtime_dir
    try:
        with bass.Port(name) as p:
            return p.last_frame_index
    except bass.BassError:
        return None


def main():
    a = sys.argv[1:]
    sep = a.index("--")
    src_dir, src, rep_dir, rep, timeout = a[0], a[1], a[2], a[3], float(a[4])
    cmd = a[sep + 1:]
    r0 = lfi(rep_dir, rep) or 0
    subprocess.run(cmd, check=True)
    t_up = time.monotonic()
    s_up = lfi(src_dir, src) or 0
    moved = live = None
    r = r0
    while time.monotonic() - t_up < timeout and live is None:
        r = lfi(rep_dir, rep)
        now = time.monotonic() - t_up
        if r is not None and r != r0 and moved is None:
            moved = now
        if r is not None and r >= s_up and moved is not None:
            live = now
        time.sleep(0.005)
    print(json.dumps({"moved_s": moved, "live_s": live, "source_lfi_at_up": s_up,
                      "replica_lfi_at_up": r0, "replica_lfi_end": r}))


if __name__ == "__main__":
    main()
