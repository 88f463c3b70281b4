"""bass: Python client of the bass audio streaming broker (ctypes over libbassclient).

Reading a port, in the vocabulary of the BASS documentation::

    import bass
    bass.acquire("sim:pattern", 44100, 2205, 20)        # the broker's Acquire service
    with bass.Port("default") as port:
        d = port.get_audio_data(12000, nfr)              # formal getAudioData, never blocks
        d.left, d.right, d.nfr, d.n, d.loss              # int32 numpy arrays, next frame, ...
        for block in port.blocks(4410, start_offs=0):    # consecutive blocks (blocking)
            ...
        c = port.chunk_info(frame)                       # the chunk holding a frame
        "GAP" in c.flag_names, c.mono_ns                 # zero-filled? when was it captured?

Frames are numbered from 1; frame 0 is the zero frame before the acquisition. Errors raise
:class:`BassError` carrying the C result code, its name and the library's message.
"""

import collections
import ctypes
import math
import numbers
import time

import numpy as np

from . import _lib
from ._lib import BASS_WAIT_FOREVER, lib

__all__ = [
    "BassError", "Port", "Writer", "AudioData", "Block", "ChunkInfo", "acquire", "devices", "stop", "status",
    "replica_status",
    "list_devices", "version", "pattern_expected", "RESULT_NAMES", "STATE_NAMES", "CHUNK_FLAGS",
]

# Result codes of include/bass.h (stable, never renumbered), generated from the library's one
# table by `make header`.
from ._results import RESULT_NAMES  # noqa: E402
for _code, _name in RESULT_NAMES.items():
    globals()["BASS_" + ("OK" if _code == 0 else "ERR_" + _name)] = _code

from ._abi import STATE_NAMES  # noqa: E402

# Chunk flags (bass.h's BASS_CHUNK_*), by name: CHUNK_GAP, CHUNK_DISCONTINUITY, ...
CHUNK_FLAGS = dict(_lib.CHUNK_FLAGS)
for _name, _bit in CHUNK_FLAGS.items():
    globals()["CHUNK_" + _name] = _bit

# Longest single wait inside the library, so that Ctrl-C (KeyboardInterrupt) is seen promptly.
WAIT_SLICE_MS = 100


class BassError(Exception):
    """A failed libbassclient call: `code` (int), `name` (e.g. "TIMEOUT"), `message`."""

    def __init__(self, call, code, message=""):
        self.call, self.code, self.message = call, code, message
        self.name = RESULT_NAMES.get(code, f"UNKNOWN_{code}")
        text = lib.bass_result_str(code).decode()
        super().__init__(f"{message or call} [{text}]")


def _check(call, code):
    if code != 0:
        raise BassError(call, code, lib.bass_last_error().decode(errors="replace"))


def _bytes(s, what="name"):
    """A str argument (or None) as NUL-terminated bytes for the C library."""
    if s is None:
        return None
    if not isinstance(s, str):
        raise TypeError(f"{what} must be a str or None, not {type(s).__name__}")
    if "\0" in s:
        raise ValueError(f"{what} must not contain NUL characters")
    return s.encode()


# Largest value of each C integer type the package passes to the library.
_C_MAX = {"uint32_t": 2**32 - 1, "uint64_t": 2**64 - 1, "size_t": 2 ** (8 * ctypes.sizeof(ctypes.c_size_t)) - 1}


def _uint(value, what, ctype="uint64_t", minimum=0):
    """`value` checked as an integer for a C `ctype` argument named `what`: ValueError if it is
    not an integer (float, NaN, None, ...) or below `minimum`, OverflowError if the C type cannot
    hold it. Checked here because ctypes would silently wrap it (2**64 + 5 becomes 5)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{what} must be an integer, not {value!r}")
    value = int(value)
    if value < minimum:
        raise ValueError(f"{what} must be >= {minimum}, not {value}")
    if value > _C_MAX[ctype]:
        raise OverflowError(f"{what} = {value} does not fit the C type {ctype} (max {_C_MAX[ctype]})")
    return value


def _int(value, what):
    """`value` checked as a Python integer of any sign (ValueError otherwise)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{what} must be an integer, not {value!r}")
    return int(value)


def _seconds(value, what):
    """A timeout in seconds: None or +inf (no limit), else a finite number >= 0."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{what} must be a number of seconds or None, not {value!r}")
    value = float(value)
    if math.isnan(value) or value < 0:
        raise ValueError(f"{what} must be >= 0 seconds (or None), not {value}")
    return None if math.isinf(value) else value


def version():
    """The library's version string."""
    return lib.bass_version().decode()


def pattern_expected(frames, channel):
    """The pattern test signal for the given frame indices (0 for the zero frame 0)."""
    f = np.asarray(frames, dtype=np.uint64)
    v = (((f & np.uint64(0x3FFFFFF)) << np.uint64(6)) | np.uint64(channel & 63)).astype(np.uint32).view(np.int32)
    return np.where(f == 0, 0, v).astype(np.int32)


AudioData = collections.namedtuple("AudioData", "left right nfr n loss")
AudioData.__doc__ = "Result of getAudioData: int32 arrays of n frames, the new nfr, n, frames lost."

Block = collections.namedtuple("Block", "left right first_frame next_frame loss")
Block.__doc__ = ("A complete block: int32 arrays, the index of its first frame, the frame after it, and "
                 "the frames lost while it was assembled (0: the block follows the previous one exactly).")


class ChunkInfo(collections.namedtuple(
        "ChunkInfo", "first_frame frames mono_ns realtime_ns flags bound_ns missing_channels unaligned_channels",
        defaults=(None, 0, 0))):
    """Timestamps and flags of one chunk (bass_chunk_info): its first frame, its frames, the
    CLOCK_MONOTONIC and CLOCK_REALTIME (ns) of its first frame, and its BASS_CHUNK_* flags;
    then what port format 2.4 adds (bass_chunk_ext): the timestamps' bound in ns (the true
    capture time of the first frame lies within mono_ns +- bound_ns; None if not known), and
    the masks of channels whose frames are not real (missing_channels) or not yet aligned
    (unaligned_channels), bit c for channel c."""

    __slots__ = ()

    @property
    def flag_names(self):
        """The names of the flags set, in bit order, e.g. ("GAP",) for zero-filled frames the
        device (or the network) did not deliver, ("LATE",) for a chunk that reached the port
        late (the capture fell behind)."""
        return tuple(name for name, bit in CHUNK_FLAGS.items() if self.flags & bit)


def _meta(flags, mono_ns, realtime_ns):
    """A bass_chunk_meta (0 timestamps: now)."""
    return _lib.ChunkMeta(_uint(mono_ns, "mono_ns"), _uint(realtime_ns, "realtime_ns"),
                          _uint(flags, "flags", "uint32_t"))


def _i32p(a, offset=0):
    return ctypes.cast(a.ctypes.data + 4 * offset, ctypes.POINTER(ctypes.c_int32))


class Port:
    """A port opened read-only (`name` = the broker's name, default "default")."""

    def __init__(self, name="default"):
        self._h = None
        h = ctypes.c_void_p()
        if name is None:
            raise TypeError("name must be a str (the broker's name, e.g. \"default\")")
        _check("bass_port_open", lib.bass_port_open(_bytes(name), ctypes.byref(h)))
        self._h = h
        self.name = name
        info = self.info()
        self.channels = info["channels"]
        self.frames_on_port = info["frames_on_port"]
        self.epoch = info["epoch"]

    def close(self):
        if self._h is not None:
            lib.bass_port_close(self._h)
            self._h = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        self.close()

    def _handle(self):
        if self._h is None:
            raise BassError("Port", 3, "the port is closed")
        return self._h

    def info(self):
        """A snapshot of the port header as a dict (state as a name, device and message as str)."""
        i = _lib.PortInfo()
        _check("bass_port_get_info", lib.bass_port_get_info(self._handle(), ctypes.byref(i)))
        d = {name: getattr(i, name) for name, _ in _lib.PortInfo._fields_}
        d["device"] = i.device.decode(errors="replace")
        d["message"] = i.message.decode(errors="replace")
        d["state_name"] = STATE_NAMES.get(i.state, str(i.state))
        d["writer_alive"] = bool(i.writer_alive)
        return d

    @property
    def last_frame_index(self):
        return self.info()["last_frame_index"]

    def chunk_info(self, frame):
        """Timestamps and flags of the chunk holding `frame` (a :class:`ChunkInfo`). Raises
        BassError FRAME_LOST if the frame left the window, FRAME_NOT_YET if it is not published."""
        frame = _uint(frame, "frame")
        c = _lib.ChunkInfo()
        _check("bass_port_chunk_info", lib.bass_port_chunk_info(self._handle(), frame, ctypes.byref(c)))
        x = _lib.ChunkExt()
        _check("bass_port_chunk_ext", lib.bass_port_chunk_ext(self._handle(), frame, ctypes.byref(x)))
        # Both calls check that the frame is still in the window: the rows are the same chunk's.
        bound = None if x.bound_ns == _lib.BASS_BOUND_UNKNOWN else x.bound_ns
        return ChunkInfo(c.first_frame, c.frames, c.mono_ns, c.realtime_ns, c.flags, bound,
                         x.missing_channels, x.unaligned_channels)

    def get_audio_data(self, n_frames, nfr):
        """The formal getAudioData: up to `n_frames` frames from `nfr` (never blocks)."""
        n_frames = _uint(n_frames, "n_frames", "size_t")
        nfr = _uint(nfr, "nfr")
        # At most nFOP frames come back: the buffers hold exactly the count passed to C.
        want = min(n_frames, self.frames_on_port)
        left = np.empty(max(1, want), dtype=np.int32)
        right = np.empty(max(1, want), dtype=np.int32)
        c_nfr, n, loss = ctypes.c_uint64(nfr), ctypes.c_size_t(), ctypes.c_uint64()
        _check("bass_get_audio_data", lib.bass_get_audio_data(
            self._handle(), want, ctypes.byref(c_nfr), _i32p(left), _i32p(right),
            ctypes.byref(n), ctypes.byref(loss)))
        return AudioData(left[:n.value], right[:n.value], c_nfr.value, n.value, loss.value)

    def get_audio_data_multi(self, n_frames, nfr, channels=None):
        """getAudioData for the first `channels` channels: returns (array[channels, n], nfr, n, loss)."""
        n_frames = _uint(n_frames, "n_frames", "size_t")
        nfr = _uint(nfr, "nfr")
        channels = self.channels if channels is None else _uint(channels, "channels", "uint32_t", minimum=1)
        if channels > self.channels:
            raise ValueError(f"channels = {channels} exceeds the port's {self.channels} channels")
        want = min(n_frames, self.frames_on_port)
        out = np.empty((channels, max(1, want)), dtype=np.int32)
        ptrs = (ctypes.POINTER(ctypes.c_int32) * channels)(*[_i32p(out[c]) for c in range(channels)])
        c_nfr, n, loss = ctypes.c_uint64(nfr), ctypes.c_size_t(), ctypes.c_uint64()
        _check("bass_get_audio_data_multi", lib.bass_get_audio_data_multi(
            self._handle(), want, ctypes.byref(c_nfr), ptrs, channels,
            ctypes.byref(n), ctypes.byref(loss)))
        return out[:, :n.value], c_nfr.value, n.value, loss.value

    def wait(self, frame, timeout=None):
        """Blocks until `frame` is published; returns the last frame index.

        Waits in slices of WAIT_SLICE_MS so that Ctrl-C raises KeyboardInterrupt promptly.
        Raises BassError TIMEOUT after `timeout` seconds (None: no limit), STOPPED, DEVICE,
        RESTARTED or WRITER_GONE when the acquisition ends.
        """
        frame = _uint(frame, "frame")
        timeout = _seconds(timeout, "timeout")
        deadline = None if timeout is None else time.monotonic() + timeout
        lfi = ctypes.c_uint64()
        while True:
            slice_ms = WAIT_SLICE_MS
            if deadline is not None:
                slice_ms = max(0, min(slice_ms, int((deadline - time.monotonic()) * 1000)))
            r = lib.bass_port_wait(self._handle(), frame, slice_ms, ctypes.byref(lfi))
            if r == 0:
                return lfi.value
            if r in (BASS_ERR_TIMEOUT, BASS_ERR_INTERRUPTED):  # noqa: F821 (defined above)
                if deadline is not None and time.monotonic() >= deadline:
                    _check("bass_port_wait", r)
                continue
            _check("bass_port_wait", r)

    def start_frame(self, start_offs=0):
        """nfr for a start offset counted from the next frame (0 = fresh frames only;
        -N = the last N frames on the port), clamped at 0, as BASC does."""
        return max(0, self.last_frame_index + 1 + _int(start_offs, "start_offs"))

    def blocks(self, n_frames, start_offs=0, nfr=None, count=None, timeout=None, max_outage=None):
        """Iterates over consecutive blocks of `n_frames` frames (blocking on the port).

        Starts at `nfr` if given, else at `start_frame(start_offs)`. Reads at least every half
        window, so no frame is lost while the consumer keeps up; frames lost anyway are
        reported in `Block.loss`. Stops after `count` blocks (None: forever).

        Rides through pauses that end by themselves -- a DEVICE error or WRITER_GONE (a
        replica's link outage, a broker restarted by systemd after its grace, a device that
        comes back): it waits for frames to flow again, and the frames missed meanwhile come as
        GAP zeros or `Block.loss`. `max_outage` (seconds) bounds such a pause: past it the
        DEVICE / WRITER_GONE BassError is raised (None: wait for ever). STOPPED and RESTARTED
        (a new acquisition: open the port again) are raised at once, as are other errors.

        Every channel of the port is read (1 to 64): `Block.left` and `Block.right` are
        channels 0 and 1 (`right` is None on a 1-channel port); all channels, as an int32 array
        of shape (channels, n_frames), are `Block.left.base` -- see `Port.block_samples`.
        """
        if n_frames <= 0:
            raise ValueError("n_frames must be > 0")
        nfr = self.start_frame(start_offs) if nfr is None else nfr
        max_outage = _seconds(max_outage, "max_outage")
        half = max(1, self.frames_on_port // 2)
        ch = self.channels
        done = 0
        paused_since = None
        while count is None or done < count:
            data = np.empty((ch, n_frames), dtype=np.int32)
            filled, loss, first = 0, 0, None
            while filled < n_frames:
                rem = n_frames - filled
                try:
                    self.wait(nfr + min(rem, half) - 1, timeout)
                    paused_since = None
                except BassError as e:
                    if e.name not in ("DEVICE", "WRITER_GONE"):
                        raise
                    now = time.monotonic()
                    paused_since = now if paused_since is None else paused_since
                    if max_outage is not None and now - paused_since >= max_outage:
                        raise
                    time.sleep(0.05)
                    continue
                want = min(rem, self.frames_on_port)
                ptrs = (ctypes.POINTER(ctypes.c_int32) * ch)(*[_i32p(data[c], filled) for c in range(ch)])
                c_nfr, n, l = ctypes.c_uint64(nfr), ctypes.c_size_t(), ctypes.c_uint64()
                _check("bass_get_audio_data_multi", lib.bass_get_audio_data_multi(
                    self._handle(), want, ctypes.byref(c_nfr), ptrs, ch, ctypes.byref(n), ctypes.byref(l)))
                if first is None and n.value:
                    first = c_nfr.value - n.value
                loss += l.value
                filled += n.value
                nfr = c_nfr.value
            done += 1
            yield Block(data[0], data[1] if ch > 1 else None, first, nfr, loss)

    @staticmethod
    def block_samples(block):
        """All channels of a block from `blocks()`: int32 array of shape (channels, n_frames)."""
        return block.left.base


class Writer:
    """A port writer (for simulators and test rigs; the broker is the writer in production)."""

    def __init__(self, name, sample_rate=44100, frames_per_chunk=2205, chunks_on_port=20, channels=2,
                 device="python"):
        self._h = None
        h = ctypes.c_void_p()
        if name is None:
            raise TypeError("name must be a str")
        sample_rate = _uint(sample_rate, "sample_rate", "uint32_t")
        frames_per_chunk = _uint(frames_per_chunk, "frames_per_chunk", "uint32_t")
        chunks_on_port = _uint(chunks_on_port, "chunks_on_port", "uint32_t")
        channels = _uint(channels, "channels", "uint32_t")
        _check("bass_writer_create", lib.bass_writer_create(
            _bytes(name), _bytes(device, "device"), sample_rate, frames_per_chunk, chunks_on_port, channels,
            ctypes.byref(h)))
        self._h = h
        self.channels, self.frames_per_chunk = channels, frames_per_chunk

    def publish(self, samples, flags=0, mono_ns=0, realtime_ns=0):
        """Publishes one chunk: int32 samples, shape (frames_per_chunk, channels) or flat interleaved,
        with its CHUNK_* `flags` and the timestamps of its first frame (0: now).
        Returns the new last frame index."""
        a = np.ascontiguousarray(samples, dtype=np.int32).reshape(-1)
        meta = _meta(flags, mono_ns, realtime_ns)
        lfi = ctypes.c_uint64()
        _check("bass_writer_publish_interleaved", lib.bass_writer_publish_interleaved(
            self._h, _i32p(a), a.size, ctypes.byref(meta), ctypes.byref(lfi)))
        return lfi.value

    def publish_gap(self, flags=0, mono_ns=0, realtime_ns=0):
        """Publishes one zero-filled chunk flagged GAP (frames the device did not deliver)."""
        meta = _meta(flags, mono_ns, realtime_ns)
        lfi = ctypes.c_uint64()
        _check("bass_writer_publish_gap", lib.bass_writer_publish_gap(self._h, ctypes.byref(meta), ctypes.byref(lfi)))
        return lfi.value

    def start_at(self, first_frame):
        """Starts a port that has published nothing at `first_frame` (which must start a chunk):
        a replica following another port's frame indices; the frames before it are lost."""
        _check("bass_writer_start_at", lib.bass_writer_start_at(self._h, _uint(first_frame, "first_frame")))

    def publish_lost(self, n_frames, flags=0, mono_ns=0, realtime_ns=0):
        """Publishes `n_frames` (whole chunks) zero-filled GAP frames standing for frames lost
        upstream or on the network (counted in gap_frames and lost_upstream_frames)."""
        meta = _meta(flags, mono_ns, realtime_ns)
        lfi = ctypes.c_uint64()
        _check("bass_writer_publish_lost", lib.bass_writer_publish_lost(
            self._h, _uint(n_frames, "n_frames"), ctypes.byref(meta), ctypes.byref(lfi)))
        return lfi.value

    def set_state(self, state, error_code=0, message=None):
        state = _uint(state, "state", "uint32_t")
        error_code = _uint(error_code, "error_code", "uint32_t")
        _check("bass_writer_set_state", lib.bass_writer_set_state(self._h, state, error_code,
                                                                  _bytes(message, "message")))

    def close(self):
        if self._h is not None:
            lib.bass_writer_close(self._h)
            self._h = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _control(name):
    if not _lib.has(name):
        raise BassError(name, 19, f"{name} is not in this libbassclient (no control plane)")
    return getattr(lib, name)


def acquire(device, sample_rate=44100, frames_per_chunk=2205, chunks_on_port=20, channels=2, broker=None):
    """The Acquire service: starts (or restarts) the broker's acquisition. Returns the epoch.
    `device` a list of names: several devices, the first the master clock, each with `channels`
    channels (bass_acquire_devices; docs/multi-device.md), or with `channels` a list of one
    count per device (bass_acquire_devices_channels)."""
    if device is None:
        raise TypeError("device must be a str, e.g. \"sim:pattern\", or a list of them")
    sample_rate = _uint(sample_rate, "sample_rate", "uint32_t")
    frames_per_chunk = _uint(frames_per_chunk, "frames_per_chunk", "uint32_t")
    chunks_on_port = _uint(chunks_on_port, "chunks_on_port", "uint32_t")
    per_device = isinstance(channels, (list, tuple))
    if per_device:
        if not isinstance(device, (list, tuple)) or len(channels) != len(device):
            raise ValueError(f"channels: a list of {len(channels)} count(s) needs as many devices, "
                             f"got {len(device) if isinstance(device, (list, tuple)) else 'one'}")
        counts = [_uint(c, f"channels[{i}]", "uint32_t") for i, c in enumerate(channels)]
    else:
        channels = _uint(channels, "channels", "uint32_t")
    epoch = ctypes.c_uint64()
    if isinstance(device, (list, tuple)):
        if not device:
            raise ValueError("device: an empty list (name the master first)")
        names = (ctypes.c_char_p * len(device))(*[_bytes(d, f"device[{i}]") for i, d in enumerate(device)])
        if per_device:
            _check("bass_acquire_devices_channels", _control("bass_acquire_devices_channels")(
                _bytes(broker, "broker"), names, (ctypes.c_uint32 * len(counts))(*counts), len(device),
                sample_rate, frames_per_chunk, chunks_on_port, ctypes.byref(epoch)))
            return epoch.value
        _check("bass_acquire_devices", _control("bass_acquire_devices")(
            _bytes(broker, "broker"), names, len(device), sample_rate, frames_per_chunk, chunks_on_port,
            channels, ctypes.byref(epoch)))
        return epoch.value
    _check("bass_acquire", _control("bass_acquire")(
        _bytes(broker, "broker"), _bytes(device, "device"), sample_rate, frames_per_chunk, chunks_on_port,
        channels, ctypes.byref(epoch)))
    return epoch.value


def devices(broker=None):
    """The devices of the broker's acquisition (bass_broker_device_info), master first, as a list
    of dicts: `name`, `role`, `state`, `first_channel`, `channels`, `ratio_ppm`,
    `error_estimate`, `locks`, `xruns`, `unplugs`, `missing_frames`, `unaligned_frames`
    (docs/multi-device.md). Empty before the first Acquire."""
    out = []
    while True:
        d = _lib.DeviceInfo()
        code = _control("bass_broker_device_info")(_bytes(broker, "broker"), len(out), ctypes.byref(d))
        if code == globals()["BASS_ERR_NOT_FOUND"]:
            return out
        _check("bass_broker_device_info", code)
        row = {name: getattr(d, name) for name, _ in _lib.DeviceInfo._fields_}
        for text in ("name", "role", "state"):
            row[text] = getattr(d, text).decode(errors="replace")
        out.append(row)


def stop(broker=None):
    """The Stop service."""
    _check("bass_stop", _control("bass_stop")(_bytes(broker, "broker")))


def status(broker=None):
    """The broker's status as a dict."""
    s = _lib.Status()
    _check("bass_status", _control("bass_status")(_bytes(broker, "broker"), ctypes.byref(s)))
    d = {name: getattr(s, name) for name, _ in _lib.Status._fields_}
    d["device"] = s.device.decode(errors="replace")
    d["message"] = s.message.decode(errors="replace")
    d["state_name"] = STATE_NAMES.get(s.state, str(s.state))
    return d


def replica_status(broker=None):
    """What a mirror says of its replica (`bass-bridge mirror --name NAME`) as a dict: the link
    (`link_up`, `link_since_s`), the source (`source`, `source_state`, `source_epoch`,
    `source_last_frame_index`), what never arrived (`gap_frames_lost`, `gap_frames_source`),
    `outages`, `forged_messages`. None when the broker is not a replica (a bassd)."""
    r = _lib.ReplicaInfo()
    code = _control("bass_replica_status")(_bytes(broker, "broker"), ctypes.byref(r))
    if code == globals()["BASS_ERR_NOT_FOUND"]:
        return None
    _check("bass_replica_status", code)
    d = {name: getattr(r, name) for name, _ in _lib.ReplicaInfo._fields_ if name != "reserved"}
    d["link_up"] = bool(r.link_up)
    d["source"] = r.source.decode(errors="replace")
    d["source_state"] = r.source_state.decode(errors="replace")
    return d


def list_devices(broker=None):
    """The ListDevices service: a list of (name, description)."""
    fn = _control("bass_list_devices")
    broker = _bytes(broker, "broker")
    size = 4096
    while True:
        buf = ctypes.create_string_buffer(size)
        out_len = ctypes.c_size_t()
        r = fn(broker, buf, size, ctypes.byref(out_len))
        if r == 22 and out_len.value > size:  # BUFFER_TOO_SMALL: out_len is the size needed
            size = out_len.value
            continue
        _check("bass_list_devices", r)
        text = buf.value.decode(errors="replace")
        return [tuple((line.split("\t", 1) + [""])[:2]) for line in text.splitlines() if line]

# Callback streams (python/bass/stream.py): not realtime; see its docstring for the GIL.
from .stream import StreamBlock, StreamEvent, StreamStop, run_stream  # noqa: E402

__all__ += ["StreamBlock", "StreamEvent", "StreamStop", "run_stream"]
