#!/usr/bin/env python3
"""The rate estimate under CPU load: a standalone measurement, ~30 s.

Starts a private bassd without real-time priority, acquires sim:pattern at exactly 48 kHz in
32-frame chunks, runs four busy loops, samples Status.rate_estimate_hz every 0.25 s for 20 s,
then stops bassd for 2 s (SIGSTOP / SIGCONT) and samples for 6 s more. With
`--load-first` the busy loops start before the Acquire, so the loop also locks under load. Prints the estimate's
range in ppm off 48 000 Hz after the lock (5..20 s) and after the stop. Needs a release build.
Run: python3 bench/rate_under_load.py
"""

import os
import signal
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET = os.environ.get("CARGO_TARGET_DIR") or os.path.join(ROOT, "target")
sys.path.insert(0, os.path.join(ROOT, "python"))
RATE = 48000


def main():
    rt = tempfile.mkdtemp(prefix="bass-rate-")
    os.environ["BASS_RUNTIME_DIR"] = rt
    import bass

    bassd = subprocess.Popen([os.path.join(TARGET, "release", "bassd"), "--name", "rate", "--rt-priority", "0",
                              "--stall-ms", "10000"], stderr=subprocess.DEVNULL)
    load_first = "--load-first" in sys.argv[1:]
    busy = []
    rows = []
    try:
        if load_first:
            busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(4)]
        for _ in range(200):
            try:
                bass.status(broker="rate")
                break
            except bass.BassError:
                time.sleep(0.05)
        bass.acquire("sim:pattern", RATE, 32, 3000, 2, broker="rate")
        if not load_first:
            busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(4)]
        t0 = time.monotonic()

        def sample():
            hz = bass.status(broker="rate")["rate_estimate_hz"]
            rows.append((time.monotonic() - t0, (hz / RATE - 1) * 1e6))

        while time.monotonic() - t0 < 20:
            sample()
            time.sleep(0.25)
        bassd.send_signal(signal.SIGSTOP)
        time.sleep(2)
        bassd.send_signal(signal.SIGCONT)
        resumed = time.monotonic() - t0
        while time.monotonic() - t0 < resumed + 6:
            sample()
            time.sleep(0.1)
    finally:
        for b in busy:
            b.kill()
        bassd.send_signal(signal.SIGCONT)
        bassd.terminate()
        bassd.wait()
    if "-v" in sys.argv[1:]:
        print(" ".join(f"{t:.1f}:{p:+.1f}" for t, p in rows))
    loaded = [p for t, p in rows if 5 < t < 20]
    after = [p for t, p in rows if t > resumed]
    late = [t - resumed for t, p in rows if t > resumed and abs(p) > 20]
    print(f"under load (5..20 s): {min(loaded):+.1f} .. {max(loaded):+.1f} ppm ({len(loaded)} samples)")
    print(f"after a 2 s SIGSTOP:  {min(after):+.1f} .. {max(after):+.1f} ppm; "
          f"last sample beyond ±20 ppm: {f'{max(late):.1f} s after SIGCONT' if late else 'none'}")


if __name__ == "__main__":
    main()
