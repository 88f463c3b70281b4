"""`bass lsl` against a real pylsl inlet (PyPI pylsl and the liblsl its wheel ships), inside a
network namespace of its own (LSL's discovery multicasts; nothing leaves the namespace's
loopback): the samples are the pattern of the frames the port published, each sample's
timestamp is its chunk's CLOCK_MONOTONIC stamp (LSL's clock is CLOCK_MONOTONIC on Linux), and
the marker stream names exactly the frames the inlet did not get as data — the zero-filled
frames of sim:xrun's overruns (`gap`) and the frames the outlet lost while it was stopped
longer than the port's window (`overrun`)."""

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import pytest

from conftest import ROOT, TARGET

BIN = os.environ.get("BASS_BIN_DIR") or os.path.join(TARGET, "release")
RATE, NFPC, NCOP = 8000, 80, 25  # a window of 2000 frames = 0.25 s

INLET = r"""
import json, sys, time
import pylsl
audio = pylsl.resolve_byprop("name", "bass-lsl", timeout=10)
marks = pylsl.resolve_byprop("name", "bass-lsl-loss", timeout=10)
assert audio and marks, "streams not found"
ia = pylsl.StreamInlet(audio[0], max_buflen=60, processing_flags=0)
im = pylsl.StreamInlet(marks[0], max_buflen=60, processing_flags=0)
info = ia.info()
desc = info.desc()
ia.open_stream(timeout=10); im.open_stream(timeout=10)
print("open", flush=True)
samples, stamps, markers = [], [], []
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    chunk, ts = ia.pull_chunk(timeout=0.2)
    samples += chunk; stamps += ts
    m, mts = im.pull_chunk(timeout=0.0)
    markers += [(x[0], t) for x, t in zip(m, mts)]
time.sleep(0.5)
m, mts = im.pull_chunk(timeout=0.5)
markers += [(x[0], t) for x, t in zip(m, mts)]
out = {"type": info.type(), "channels": info.channel_count(), "rate": info.nominal_srate(),
       "format": info.channel_format(), "broker": desc.child("bass").child_value("broker"),
       "nfpc": desc.child("bass").child_value("frames_per_chunk"),
       "samples": samples, "stamps": stamps, "markers": markers,
       "local_clock": pylsl.local_clock(), "monotonic": time.clock_gettime(time.CLOCK_MONOTONIC)}
print(json.dumps(out))
"""

LSL_CFG = """[ports]
IPv6 = disable
[multicast]
ResolveScope = machine
[lab]
KnownPeers = {127.0.0.1}
"""


def frame_of(sample0):
    """The frame (low 26 bits) a pattern sample of channel 0 names."""
    return (sample0 & 0xFFFFFFFF) >> 6


@pytest.fixture
def netns():
    if os.geteuid() != 0 or not shutil.which("ip"):
        pytest.skip("needs root and ip (a network namespace for LSL's discovery)")
    try:
        import pylsl  # noqa: F401
    except ImportError:
        pytest.skip("PyPI pylsl is not installed (make deps)")
    ns = f"basslsl{os.getpid()}"
    subprocess.run(["ip", "netns", "add", ns], check=True)
    try:
        subprocess.run(["ip", "-n", ns, "link", "set", "lo", "up"], check=True)
        subprocess.run(["ip", "-n", ns, "link", "set", "lo", "multicast", "on"], check=True)
        yield ns
    finally:
        subprocess.run(["ip", "netns", "delete", ns], check=False)


def test_an_lsl_inlet_gets_the_pattern_stamped_and_every_missing_frame_marked(netns):
    work = tempfile.mkdtemp(prefix="bass-lsl-")
    procs = []
    try:
        cfg = os.path.join(work, "lsl_api.cfg")
        open(cfg, "w").write(LSL_CFG)
        env = dict(os.environ, BASS_RUNTIME_DIR=work, LSLAPICFG=cfg, PYTHONPATH=os.path.join(ROOT, "python"))
        inns = ["ip", "netns", "exec", netns]

        def start(args, **kw):
            p = subprocess.Popen(inns + args, env=env, **kw)
            procs.append(p)
            return p

        start([os.path.join(BIN, "bassd"), "--name", "lsl", "--rt-priority", "0", "--acquire", "sim:xrun",
               "--rate", str(RATE), "--frames", str(NFPC), "--chunks", str(NCOP), "--channels", "2"],
              stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while not os.path.exists(os.path.join(work, "bass-lsl.port")):
            assert time.monotonic() < deadline, "bassd made no port"
            time.sleep(0.05)
        outlet = start([os.path.join(BIN, "bass"), "--name", "lsl", "lsl", "--seconds", "9"],
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        inlet = start([sys.executable, "-c", INLET, "5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert inlet.stdout.readline().strip() == "open", inlet.stderr.read()
        # Stopped three times the window: the outlet loses frames to the port, and says so.
        time.sleep(2.0)
        outlet.send_signal(signal.SIGSTOP)
        time.sleep(0.8)
        outlet.send_signal(signal.SIGCONT)
        out, err = inlet.communicate(timeout=30)
        assert inlet.returncode == 0, err
        got = json.loads(out.splitlines()[-1])
        o_out, o_err = outlet.communicate(timeout=30)
        assert outlet.returncode == 0, o_err
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGCONT)
                p.terminate()
                try:
                    p.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    p.kill()
        shutil.rmtree(work, ignore_errors=True)

    assert (got["type"], got["channels"], got["rate"], got["broker"], got["nfpc"]) == ("Audio", 2, RATE, "lsl", str(NFPC))
    assert abs(got["local_clock"] - got["monotonic"]) < 0.001, "LSL's clock is CLOCK_MONOTONIC here"
    samples, stamps = got["samples"], got["stamps"]
    assert len(samples) > 3 * RATE and len(samples) == len(stamps), f"{len(samples)} samples"
    markers = [(json.loads(m), t) for m, t in got["markers"]]
    assert any(m["cause"] == "overrun" for m, _ in markers), f"no overrun marker: {markers}"
    # Each sample's stamp is its frame's capture time: consecutive frames are 1/rate apart, so
    # the stamps give every sample's frame. A step of k frames between two samples is a loss
    # of k - 1 frames, which an overrun marker stamped at the first lost frame must name; a
    # run of zero samples is a gap (sim:xrun's overruns, zero-filled), which a gap marker
    # stamped at its first frame must name; no marker inside the span names anything else.
    def marker_at(t, cause):
        hits = [m for m, mt in markers if m["cause"] == cause and abs(mt - t) < 2e-6]
        assert len(hits) == 1, f"{cause} at {t}: {hits} of {markers}"
        return hits[0]

    matched, zeros_from, pattern = set(), None, None
    for i, (smp, t) in enumerate(zip(samples, stamps)):
        if i > 0:
            k = round((t - stamps[i - 1]) * RATE)
            assert k >= 1, f"sample {i}: stamps not increasing"
            if k > 1:
                m = marker_at(stamps[i - 1] + 1 / RATE, "overrun")
                assert m["frames"] == k - 1, (m, k)
                matched.add((m["first_frame"], "overrun"))
                pattern = None
        if smp == [0, 0]:
            if zeros_from is None:
                zeros_from = i
            continue
        if zeros_from is not None and zeros_from > 0:
            m = marker_at(stamps[zeros_from], "gap")
            assert m["frames"] == round((t - stamps[zeros_from]) * RATE), (m, i - zeros_from)
            matched.add((m["first_frame"], "gap"))
            pattern = None
        zeros_from = None
        # Real frames: the pattern, channel 1 = channel 0 + 1, one frame after the other.
        assert smp[0] & 63 == 0 and smp[1] == smp[0] | 1, f"sample {i}: {smp}"
        f = frame_of(smp[0])
        assert pattern is None or f == (pattern + 1) & 0x3FFFFFF, f"sample {i}: frame {f} after {pattern}"
        pattern = f
    if zeros_from is not None and zeros_from > 0:
        # The span ended inside a gap: its marker names it (its end was not received).
        matched.add((marker_at(stamps[zeros_from], "gap")["first_frame"], "gap"))
    inside = {(m["first_frame"], m["cause"]) for m, mt in markers if stamps[0] < mt < stamps[-1]}
    assert inside == matched, f"markers naming nothing received: {inside - matched}"
    gaps = [m for m, _ in markers if (m["first_frame"], m["cause"]) in matched and m["cause"] == "gap"]
    assert len(gaps) >= 4, f"sim:xrun loses frames twice a second: {gaps}"
    assert "LSL's clock = CLOCK_MONOTONIC" in o_out and " frames lost" in o_out, o_out
