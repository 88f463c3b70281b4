"""Sizes, counts and indices are checked in Python before they reach the C library: the
exception names the argument, and ctypes never wraps or truncates a value."""

import os
import subprocess
import sys

import numpy as np
import pytest

import bass

HERE = os.path.dirname(os.path.abspath(__file__))


def test_every_public_function_survives_hostile_values_in_a_child_interpreter(runtime_dir):
    p = subprocess.run([sys.executable, os.path.join(HERE, "hostile_calls.py")], capture_output=True,
                       text=True, timeout=120, env=dict(os.environ, BASS_RUNTIME_DIR=str(runtime_dir)))
    assert p.returncode == 0, f"exit {p.returncode}\n{p.stdout}\n{p.stderr}"
    assert "ok" in p.stdout.splitlines()[-1], p.stdout


def test_a_negative_frame_count_is_refused_before_it_reaches_the_library():
    # Before: n_frames = -5 became SIZE_MAX - 4 and 12 frames were written into a 1-element array.
    with bass.Writer("p", frames_per_chunk=4, chunks_on_port=3) as w, bass.Port("p") as port:
        w.publish(np.zeros((4, 2), dtype=np.int32))
        with pytest.raises(ValueError, match="n_frames"):
            port.get_audio_data_multi(-5, 1, channels=1)
        with pytest.raises(ValueError, match="n_frames"):
            port.get_audio_data(-5, 1)
        with pytest.raises(ValueError, match="nfr"):
            port.get_audio_data(4, -1)
        with pytest.raises(ValueError, match="channels"):
            port.get_audio_data_multi(4, 1, channels=0)
        with pytest.raises(ValueError, match="channels"):
            port.get_audio_data_multi(4, 1, channels=3)


@pytest.mark.parametrize("kwargs, name", [
    (dict(sample_rate=2**32 + 48000), "sample_rate"),
    (dict(frames_per_chunk=2**32 + 480), "frames_per_chunk"),
    (dict(chunks_on_port=2**32 + 100), "chunks_on_port"),
    (dict(channels=2**32 + 2), "channels"),
])
def test_acquire_values_too_big_for_uint32_raise_overflow_naming_the_argument(kwargs, name):
    # Before: ctypes cut 2**32 + 48000 to 48000 and the broker started a 48 kHz acquisition.
    args = dict(sample_rate=48000, frames_per_chunk=480, chunks_on_port=100, channels=2, broker="no-such-broker")
    args.update(kwargs)
    with pytest.raises(OverflowError, match=name):
        bass.acquire("sim:pattern", **args)


@pytest.mark.parametrize("value", [1.5, float("nan"), None, "48000"])
def test_acquire_refuses_a_non_integer_rate(value):
    with pytest.raises(ValueError, match="sample_rate"):
        bass.acquire("sim:pattern", value, 480, 100, broker="no-such-broker")


def test_wait_for_a_frame_past_uint64_raises_instead_of_returning_at_once():
    # Before: wait(2**64 + 5) waited for frame 5, already published, and returned at once.
    with bass.Writer("p", frames_per_chunk=4, chunks_on_port=3) as w, bass.Port("p") as port:
        for _ in range(2):
            w.publish(np.zeros((4, 2), dtype=np.int32))
        with pytest.raises(OverflowError, match="frame"):
            port.wait(2**64 + 5, timeout=0)
        with pytest.raises(ValueError, match="frame"):
            port.wait(-1, timeout=0)
        with pytest.raises(ValueError, match="timeout"):
            port.wait(1, timeout=float("nan"))
        with pytest.raises(ValueError, match="timeout"):
            port.wait(1, timeout=-1)
        assert port.wait(8, timeout=float("inf")) == 8


def test_writer_geometry_past_uint32_raises_overflow():
    with pytest.raises(OverflowError, match="frames_per_chunk"):
        bass.Writer("p", frames_per_chunk=2**32 + 4, chunks_on_port=3)
    with pytest.raises(OverflowError, match="channels"):
        bass.Writer("p", channels=2**32 + 2)


def test_the_python_result_names_are_the_headers():
    """bass.RESULT_NAMES mirrors include/bass.h's bass_result (one definition of every fact)."""
    header = open(os.path.join(HERE, "..", "..", "include", "bass.h")).read()
    body = header[:header.index("} bass_result;")]
    body = body[body.rindex("{") + 1:]
    want = {}
    for line in body.splitlines():
        line = line.strip().rstrip(",")
        if line.startswith("BASS_"):
            name, value = (t.strip() for t in line.split("="))
            want[int(value)] = name.removeprefix("BASS_ERR_").removeprefix("BASS_")
    assert bass.RESULT_NAMES == want
