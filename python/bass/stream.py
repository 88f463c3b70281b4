"""Callback streams for Python (the C API's bass_stream_*, docs/c-api.md "Callback streams").

`run_stream(port, on_block, ...)` runs the stream (calling back on a thread of its own) until
`on_block` or `on_event` returns False, `StreamStop.stop()` is called, or an error ends it. Each block comes
as a `StreamBlock`: its absolute first frame, its frame count, the frames lost before it, its
chunk flags, timestamps and the rate estimate, and its samples as an int32 numpy array of
shape (frames, channels) — a copy, so it may be kept.

Not realtime: every callback takes the GIL (ctypes acquires it to call Python) and allocates
Python objects. A callback slower than the port's window is lapped, and the next block says
exactly how many frames were lost. While a callback runs, other Python threads wait for the
GIL; while the stream waits for frames, the GIL is released (the C call is made without it).
An exception raised by a callback stops the stream and is raised again by `run_stream`.

The stream runs on a thread of its own (`bass-stream`, which calls the callbacks) while the
calling thread waits for it in slices of 25 ms: Ctrl-C (KeyboardInterrupt, or any exception a
signal handler raises) ends `run_stream` within about 75 ms whatever the stream is doing —
blocks flowing, or a broker that is stopped or frozen — once the callback that is running
returns: the signal is seen within 25 ms, the stream is stopped (a waiting stream notices
within 50 ms) and closed, and the exception is raised. Measured (python/tests/
test_stream_interrupt.py): 10 ms while blocks flow, 40-50 ms with the broker SIGSTOPped.
"""

import collections
import ctypes
import threading

import numpy as np

from . import _lib
from ._lib import lib

EVENT_NAMES = {1: "stopped", 2: "restarted", 3: "device", 4: "writer_gone", 5: "realtime_refused", 6: "resumed"}
START = {"oldest": 0, "now": 1}
# How long the calling thread waits for the stream at a time: the bound on seeing a signal.
WAIT_SLICE_S = 0.025


class StreamBlock(collections.namedtuple(
        "StreamBlock", "epoch first_frame frames lost flags mono_ns realtime_ns rate_hz channels samples")):
    """One block: `samples` is an int32 array of shape (frames, len(channels)); `channels` the
    port channels of its columns."""


class StreamEvent(collections.namedtuple("StreamEvent", "kind code epoch frame os_error message")):
    """An event: `kind` is "stopped" (frame = last frame), "restarted" (epoch, frame = where the
    stream resumes), "device" (code = BASS_DEVERR_*, message), "writer_gone" (code = pid),
    "resumed" (after stopped, device or writer_gone: the same acquisition goes on; frame = the
    next frame read) or "realtime_refused" (os_error). `epoch` is the stream's current epoch."""


class StreamStop:
    """Stops a running stream from any thread or from inside its callbacks."""

    def __init__(self):
        self._h = None
        self._asked = False

    def stop(self):
        self._asked = True
        if self._h is not None:
            lib.bass_stream_stop(self._h)


def run_stream(port, on_block, on_event=None, frames_per_call=0, start="oldest", channels=None,
               stopper=None):
    """Runs a callback stream over `port` (a bass.Port) until it ends. `start` is "oldest",
    "now" or a frame index; `channels` the port channels wanted (None: all; an empty list is
    refused). `on_block(block)` and `on_event(event)` return False to stop (anything else goes
    on; without `on_event`, every event ends the stream); they are called on the stream's own
    thread. Returns when the stream ends; raises what a callback raised, or a signal's
    exception (KeyboardInterrupt) within about 75 ms of the signal."""
    from . import _check, _uint  # the package's argument checks

    if not _lib.has("bass_stream_create"):
        raise OSError("the loaded libbassclient has no callback streams (bass_stream_create)")
    cfg = _lib.StreamConfig()
    cfg.frames_per_call = _uint(frames_per_call, "frames_per_call", "size_t")
    if isinstance(start, str):
        if start not in START:
            raise ValueError(f"start = {start!r} ('oldest', 'now' or a frame index)")
        cfg.start = START[start]
    else:
        cfg.start, cfg.start_frame = 2, _uint(start, "start")
    chans = None
    if channels is not None:
        channels = list(channels)
        if not channels:
            raise ValueError("channels = [] selects no channel: give None for every channel, or the channels wanted")
        chans = (ctypes.c_uint32 * len(channels))(*[_uint(c, "channel", "uint32_t") for c in channels])
        cfg.channels, cfg.n_channels = ctypes.cast(chans, ctypes.POINTER(ctypes.c_uint32)), len(channels)
    failure = []

    def block_cb(p, _user):
        try:
            b = p.contents
            n, k = b.frames, b.n_channels
            samples = np.empty((n, k), dtype=np.int32)
            for c in range(k):
                samples[:, c] = np.ctypeslib.as_array(b.channels[c], shape=(n,))
            chs = tuple(b.port_channels[c] for c in range(k))
            block = StreamBlock(b.epoch, b.first_frame, n, b.lost, b.flags, b.mono_ns, b.realtime_ns, b.rate_hz,
                                chs, samples)
            return 1 if on_block(block) is False else 0
        except BaseException as e:  # noqa: B036 - carried to run_stream, never into C
            failure.append(e)
            return 1

    def event_cb(p, _user):
        if on_event is None:
            return 0 if p.contents.kind == 5 else 1  # a refused priority is no end
        try:
            e = p.contents
            ev = StreamEvent(EVENT_NAMES.get(e.kind, str(e.kind)), e.code, e.epoch, e.frame, e.os_error,
                             (e.message or b"").decode(errors="replace"))
            return 1 if on_event(ev) is False else 0
        except BaseException as e:  # noqa: B036
            failure.append(e)
            return 1

    bcb, ecb = _lib.BLOCK_FN(block_cb), _lib.EVENT_FN(event_cb)  # kept alive for the run
    h = ctypes.c_void_p()
    _check("bass_stream_create",
           lib.bass_stream_create(port._handle(), ctypes.byref(cfg), bcb, ecb, None, ctypes.byref(h)))
    result = []
    runner = threading.Thread(target=lambda: result.append(lib.bass_stream_run(h)), name="bass-stream",
                              daemon=True)
    try:
        if stopper is not None:
            stopper._h = h
            if stopper._asked:
                return
        runner.start()
        # Short slices: the signal handlers run on this thread between them.
        while runner.is_alive():
            runner.join(WAIT_SLICE_S)
        if failure:
            raise failure[0]
        _check("bass_stream_run", result[0])
    finally:
        if stopper is not None:
            stopper._h = None
        if runner.is_alive():  # ended here by an exception (a signal): stop the stream first
            lib.bass_stream_stop(h)
            _join_through_signals(runner)
        lib.bass_stream_close(h)
        del chans, bcb, ecb


def _join_through_signals(t):
    """Waits for `t`, which has been asked to stop; a signal's exception meanwhile is raised
    once it has ended (the stream must not be closed while it runs)."""
    pending = None
    while t.is_alive():
        try:
            t.join(WAIT_SLICE_S)
        except BaseException as e:  # noqa: B036 - re-raised below
            pending = pending or e
    if pending is not None:
        raise pending
