"""The Python package's control plane and the C++ example against a live broker / port."""

import os
import re
import subprocess
import time

import numpy as np
import pytest

import bass


def test_python_acquire_status_blocks_and_stop_through_the_broker(broker):
    names = [n for n, _ in bass.list_devices(broker=broker)]
    assert "sim:pattern" in names
    epoch = bass.acquire("sim:pattern", 48000, 480, 10, broker=broker)
    with bass.Port(broker) as port:
        assert port.epoch == epoch
        blocks = list(port.blocks(1000, nfr=1, count=5, timeout=5))
        for k, b in enumerate(blocks):
            assert (b.first_frame, b.next_frame, b.loss) == (1 + 1000 * k, 1001 + 1000 * k, 0)
            frames = np.arange(b.first_frame, b.next_frame)
            np.testing.assert_array_equal(b.left, bass.pattern_expected(frames, 0))
            np.testing.assert_array_equal(b.right, bass.pattern_expected(frames, 1))
        s = bass.status(broker=broker)
        assert (s["state_name"], s["sample_rate"], s["frames_per_chunk"], s["chunks_on_port"], s["epoch"]) == \
            ("capturing", 48000, 480, 10, epoch)
        assert s["device"].startswith("sim:pattern") and s["last_frame_index"] >= 5000
        # A bassd is no mirror's replica (tests/bridge/outage_long.sh reads a real replica).
        assert bass.replica_status(broker=broker) is None
        bass.stop(broker=broker)
        with pytest.raises(bass.BassError) as e:
            port.wait(2**40, timeout=5)
        assert e.value.code == bass.BASS_ERR_STOPPED


def test_python_acquire_of_an_unknown_device_fails_with_the_brokers_message(broker):
    with pytest.raises(bass.BassError) as e:
        bass.acquire("no-such-device-xyz", broker=broker)
    assert e.value.code == bass.BASS_ERR_BROKER and e.value.name == "BROKER"
    assert "no-such-device-xyz" in e.value.message


def test_cpp_blocks_example_reads_consecutive_pattern_blocks(live_port, clients_env):
    exe = os.path.join(clients_env["CLIENTS_BIN"], "blocks_cpp")
    p = subprocess.run([exe, "--port", live_port, "--check-pattern", "4", "4410", "-4410"], env=clients_env,
                       capture_output=True, text=True, timeout=30)
    assert p.returncode == 0, p.stderr
    lines = [l for l in p.stdout.splitlines() if l.startswith("block ")]
    assert len(lines) == 4
    spans = [tuple(map(int, l.split("frames ")[1].split(",")[0].split(".."))) for l in lines]
    assert all(b - a == 4409 for a, b in spans)
    assert all(spans[i + 1][0] == spans[i][1] + 1 for i in range(3))
    assert all(", lost 0," in l for l in lines)


def test_cpp_errors_carry_the_result_code(clients_env):
    exe = os.path.join(clients_env["CLIENTS_BIN"], "blocks_cpp")
    p = subprocess.run([exe, "--port", "no-such-port"], env=clients_env, capture_output=True, text=True, timeout=30)
    assert p.returncode == 1
    assert "[code 4]" in p.stderr and "no-such-port" in p.stderr


def test_python_wait_is_interrupted_by_ctrl_c(live_port, clients_env):
    import signal
    import sys

    from conftest import ROOT

    code = "import bass, sys; p = bass.Port(sys.argv[1]); print('waiting', flush=True); p.wait(2**60)"
    env = dict(clients_env, PYTHONPATH=os.path.join(ROOT, "python"))
    proc = subprocess.Popen([sys.executable, "-c", code, live_port], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "waiting\n"
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=10)
    assert proc.returncode != 0 and "KeyboardInterrupt" in err


def test_cpp_example_acquires_through_the_broker_and_reads_from_its_first_frames(broker, clients_env):
    exe = os.path.join(clients_env["CLIENTS_BIN"], "blocks_cpp")
    p = subprocess.run([exe, "--port", broker, "--acquire", "sim:pattern", "--check-pattern", "3", "2205", "-100000"],
                       env=clients_env, capture_output=True, text=True, timeout=30)
    assert p.returncode == 0, p.stderr
    assert "device sim:pattern: Simulated: test pattern" in p.stdout
    assert re.search(r"acquired sim:pattern\S*: epoch \d+, state 1, 44100 Hz", p.stdout), p.stdout
    # startOffs reaching before frame 0 is clamped to 0: the first block starts with the zero frame
    assert "block 1: frames 0..2204, lost 0," in p.stdout


def test_python_sees_the_gap_of_a_device_overrun_in_chunk_info_and_info(broker):
    """sim:xrun at 8000 Hz loses 407 frames after frame 4000: with 100-frame chunks, frames
    4001..4400 come as GAP chunks (timestamps estimated), 4401.. as the DISCONTINUITY after it."""
    bass.acquire("sim:xrun", 8000, 100, 200, broker=broker)  # a 2.5 s window
    with bass.Port(broker) as port:
        port.wait(4600, timeout=10)
        before, gaps, after = port.chunk_info(4000), [port.chunk_info(f) for f in (4001, 4200, 4400)], \
            port.chunk_info(4401)
        assert before.first_frame == 3901 and before.flag_names == ()
        assert [c.first_frame for c in gaps] == [4001, 4101, 4301]
        assert all(c.flag_names == ("GAP", "TIME_ESTIMATED") and c.frames == 100 for c in gaps)
        assert after.first_frame == 4401 and "DISCONTINUITY" in after.flag_names and "GAP" not in after.flag_names
        # Timestamps are the frames' due times: 100 frames at 8000 Hz = 12.5 ms per chunk.
        assert gaps[0].mono_ns - before.mono_ns == 12_500_000
        # An overrun every half second restarts the rate loop before its 1 s window fills: every
        # chunk has the a-priori bound, one chunk's duration (12.5 ms, more than 1 ms).
        assert {c.bound_ns for c in [before, *gaps, after]} == {12_500_000}
        assert (before.missing_channels, before.unaligned_channels) == (0, 0)
        assert after.realtime_ns > gaps[-1].realtime_ns > 0
        i = port.info()
        assert set(i) >= {name for name, _ in bass._lib.PortInfo._fields_}
        assert i["xruns"] >= 1 and i["gap_frames"] >= 407 and i["lost_upstream_frames"] == 0
        assert 0 < i["started_mono_ns"] <= before.mono_ns <= i["heartbeat_mono_ns"]
        d = port.get_audio_data(400, 4001)
        assert d.n == 400 and not d.left.any() and not d.right.any()  # GAP frames are zeros
    bass.stop(broker=broker)


def test_python_chunks_of_a_settled_device_carry_a_bound_narrower_than_the_a_priori_one(broker):
    """sim:pattern at 8000 Hz, 100-frame chunks: the first second's chunks carry the a-priori
    bound (12.5 ms); once the rate loop's window has filled, the bound comes from the stamps'
    lower envelope: positive, and below the a-priori one."""
    bass.acquire("sim:pattern", 8000, 100, 400, broker=broker)  # a 5 s window
    with bass.Port(broker) as port:
        port.wait(8000 * 3, timeout=10)
        first, late = port.chunk_info(1), port.chunk_info(8000 * 3)
        assert first.bound_ns == 12_500_000
        assert late.bound_ns is not None and 0 < late.bound_ns < 12_500_000, late
    bass.stop(broker=broker)


def test_python_opening_a_port_file_that_never_became_valid_is_never_ready(clients_env):
    rt = clients_env["BASS_RUNTIME_DIR"]
    path = os.path.join(rt, "bass-py-stale.port")
    with open(path, "wb") as f:
        f.write(bytes(8192))  # format version 0: nobody is writing a header
    try:
        seen = []
        deadline = time.monotonic() + 30
        while not seen or seen[-1] == "NOT_READY":  # NOT_READY while the file is young (2 s)
            assert time.monotonic() < deadline, seen
            with pytest.raises(bass.BassError) as e:
                bass.Port("py-stale")
            seen.append(e.value.name)
            time.sleep(0.05)
        assert seen[-1] == "NEVER_READY" and e.value.code == bass.BASS_ERR_NEVER_READY, seen
        assert "py-stale" in e.value.message
    finally:
        os.unlink(path)
