"""Drives every public function of the bass package with hostile values; run as a script in its
own process by test_hostile_args.py, so that a crash of the interpreter (a heap corruption, a
segfault, an abort) shows as a failed test, not as a dead test runner.

Every call must return or raise one of the documented exceptions (ValueError, OverflowError,
TypeError, BassError); anything else, or a crash, fails. Prints "hostile calls: N ok" at the end.
"""

import itertools
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import bass  # noqa: E402

ALLOWED = (ValueError, OverflowError, TypeError, bass.BassError)
# Hostile values of every kind: negative, zero, past every C integer type, non-integer, missing.
HOSTILE = [-1, -5, -(2**63), 0, 2**31, 2**32, 2**32 + 2, 2**63, 2**64, 2**64 + 5, 2**128, 1.5, -0.5, 0.0,
           float("nan"), float("inf"), -float("inf"), None, "5", b"5", True, np.int64(-3), np.uint64(2**64 - 1),
           np.float64(2.0), [1], 1 + 2j]
# Hostile values that may be valid yet ask the library for something big: used only where the
# library bounds the work (reads are capped at the window).
BIG_VALID = [2**32 - 1, 2**64 - 1]
calls = 0


def attempt(what, fn, *args, **kwargs):
    global calls
    calls += 1
    try:
        r = fn(*args, **kwargs)
        if hasattr(r, "__next__"):  # a generator (blocks): run its first step
            next(r)
    except ALLOWED:
        pass
    except StopIteration:
        pass
    except MemoryError:
        if fn.__name__ != "blocks":
            raise
    except Exception as e:  # noqa: BLE001 (the point: nothing else may come out)
        raise AssertionError(f"{what}{args}{kwargs}: unexpected {type(e).__name__}: {e}") from e


def vary(what, fn, defaults, values, **fixed):
    """Calls fn with each argument in turn replaced by each value, the others at their default."""
    for i, v in itertools.product(range(len(defaults)), values):
        args = list(defaults)
        args[i] = v
        attempt(what, fn, *args, **fixed)


def main():
    w = bass.Writer("hostile", channels=2, sample_rate=48000, frames_per_chunk=4, chunks_on_port=3)
    chunk = np.arange(8, dtype=np.int32).reshape(4, 2)
    w.publish(chunk)
    port = bass.Port("hostile")

    for v in HOSTILE + BIG_VALID:
        attempt("get_audio_data", port.get_audio_data, v, 1)
        attempt("get_audio_data", port.get_audio_data, 4, v)
        for c in (None, 1, 2):
            attempt("get_audio_data_multi", port.get_audio_data_multi, v, 1, channels=c)
            attempt("get_audio_data_multi", port.get_audio_data_multi, 4, v, channels=c)
        attempt("get_audio_data_multi", port.get_audio_data_multi, 4, 1, channels=v)
        attempt("get_audio_data_multi", port.get_audio_data_multi, -5, 1, channels=v)
        attempt("wait", port.wait, v, timeout=0)      # a frame far ahead times out at once
        attempt("wait", port.wait, 1, timeout=v)      # frame 1 is published: returns at once
        attempt("start_frame", port.start_frame, v)
        attempt("blocks", port.blocks, v, nfr=1, count=1, timeout=0)
        attempt("blocks", port.blocks, 2, nfr=v, count=1, timeout=0)
        attempt("blocks", port.blocks, 2, start_offs=v, count=1, timeout=0)
        attempt("Port", bass.Port, v)
        attempt("publish", w.publish, v)
        attempt("set_state", w.set_state, 1, v)
        attempt("pattern_expected", bass.pattern_expected, v, 0)
        for f in (bass.status, bass.stop, bass.list_devices):
            attempt(f.__name__, f, broker=v)
    for v in HOSTILE:
        attempt("set_state", w.set_state, v)
        vary("Writer", bass.Writer, ["hostile2", 2, 48000, 4, 3], [v])
        vary("acquire", bass.acquire, ["sim:pattern", 48000, 480, 10, 2], [v], broker="no-such-broker-hostile")
    vary("acquire", bass.acquire, ["sim:pattern", 48000, 480, 10, 2], BIG_VALID, broker="no-such-broker-hostile")

    # The reads still work and return what was published.
    d = port.get_audio_data(4, 1)
    assert d.n == 4 and d.left.tolist() == [0, 2, 4, 6], d
    x, nfr, n, loss = port.get_audio_data_multi(4, 1, channels=1)
    assert n == 4 and x.shape == (1, 4) and x[0].tolist() == [0, 2, 4, 6]
    port.close()
    w.close()
    print(f"hostile calls: {calls} ok")


if __name__ == "__main__":
    main()
