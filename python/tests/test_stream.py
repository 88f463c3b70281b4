"""Callback streams from Python (bass.run_stream): the blocks tile the stream of a real port —
every frame delivered once or counted lost — across a lapped callback, sample by sample
against the pattern; an exception in a callback reaches the caller; a stop from another
thread ends a waiting stream."""

import threading

import numpy as np
import pytest

import bass

NFPC, NCOP, CH = 16, 8, 2


def pattern_chunk(first):
    frames = np.arange(first, first + NFPC, dtype=np.uint64)
    return np.stack([bass.pattern_expected(frames, c) for c in range(CH)], axis=1).astype(np.int32)


def publish(w, lfi):
    return w.publish(pattern_chunk(lfi + 1))


def test_blocks_tile_the_stream_across_a_lapped_callback():
    w = bass.Writer("pystream", 48000, NFPC, NCOP, CH)
    lfi = 0
    for _ in range(3):
        lfi = publish(w, lfi)
    state = {"lfi": lfi, "next": 1, "delivered": 0, "lost": 0, "calls": 0, "last": None}

    def on_block(b):
        s = state
        assert b.first_frame == s["next"] + b.lost
        frames = np.arange(b.first_frame, b.first_frame + b.frames, dtype=np.uint64)
        for k, c in enumerate(b.channels):
            assert np.array_equal(b.samples[:, k], bass.pattern_expected(frames, c))
        s["next"], s["calls"] = b.first_frame + b.frames, s["calls"] + 1
        s["delivered"] += b.frames
        s["lost"] += b.lost
        if s["calls"] == 5:
            for _ in range(NCOP * 2 + 3):  # a slow callback: lapped
                s["lfi"] = publish(w, s["lfi"])
        elif s["calls"] == 20:
            s["lfi"] = publish(w, s["lfi"])
            w.set_state(2)  # stopped
        elif s["calls"] < 20:
            while s["lfi"] < b.first_frame + 2 * b.frames:
                s["lfi"] = publish(w, s["lfi"])

    def on_event(e):
        assert e.kind == "stopped"
        state["last"] = e.frame
        return False

    with bass.Port("pystream") as p:
        bass.run_stream(p, on_block, on_event, channels=[1, 0])
    s = state
    assert s["last"] is not None and s["next"] == s["last"] + 1
    assert 1 + s["delivered"] + s["lost"] == s["next"]
    assert s["lost"] > NFPC * NCOP
    w.close()


def test_an_exception_in_the_callback_reaches_the_caller():
    w = bass.Writer("pythrow", 48000, NFPC, NCOP, CH)
    publish(w, 0)

    def on_block(b):
        raise KeyError("from the callback")

    with bass.Port("pythrow") as p, pytest.raises(KeyError):
        bass.run_stream(p, on_block)
    w.close()


def test_a_stop_from_another_thread_ends_a_waiting_stream():
    w = bass.Writer("pystop", 48000, NFPC, NCOP, CH)
    stopper = bass.StreamStop()
    timer = threading.Timer(0.05, stopper.stop)
    timer.start()
    with bass.Port("pystop") as p:
        bass.run_stream(p, lambda b: None, start="now", stopper=stopper)
    timer.join()
    with bass.Port("pystop") as p, pytest.raises(ValueError):
        bass.run_stream(p, lambda b: None, start="later")
    w.close()
