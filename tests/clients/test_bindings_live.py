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
