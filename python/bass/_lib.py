"""Loads libbassclient and declares the C ABI of include/bass.h for ctypes.

The library is found, in order: $BASS_LIB (a path to libbassclient.so), the workspace's
build directory ($CARGO_TARGET_DIR or target/, release build) when this package runs from
the source tree, then the dynamic loader's search (an installed library: by the name
ctypes.util.find_library gives from ld.so.cache, then by its SONAME libbassclient.so.0, then
as libbassclient.so), then the libdir that pkg-config reports for `bassclient` (an install
under a prefix the loader does not search, e.g. `make install PREFIX=/opt/bass` with
PKG_CONFIG_PATH set). Installed by the Debian package (in /usr/lib/python3/dist-packages),
this package is not in a source tree and loads the package's /usr/lib/libbassclient.so.0.
"""

import ctypes
import ctypes.util
import os
import shutil
import subprocess

from ctypes import POINTER, c_char, c_char_p, c_double, c_int, c_size_t, c_uint32, c_uint64, c_void_p

BASS_DEVICE_LEN = 128
BASS_MESSAGE_LEN = 256
BASS_SOURCE_STATE_LEN = 32
BASS_WAIT_FOREVER = 0xFFFFFFFF

# The BASS_CHUNK_* flags of include/bass.h, by name without the prefix, in the header's order
# (python/tests/test_abi_layout.py fails when the header has another set or other values).
CHUNK_FLAGS = {"GAP": 1, "DISCONTINUITY": 2, "TIME_ESTIMATED": 4, "LATE": 8}


def _candidates():
    env = os.environ.get("BASS_LIB")
    if env:
        yield env
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    # Only a source tree's python/bass looks for a build directory (an installed copy must
    # not pick up a build tree's library through $CARGO_TARGET_DIR).
    if os.path.isfile(os.path.join(root, "Cargo.toml")):
        target = os.environ.get("CARGO_TARGET_DIR") or os.path.join(root, "target")
        yield os.path.join(target, "release", "libbassclient.so")
        yield os.path.join(root, "target", "release", "libbassclient.so")
    found = ctypes.util.find_library("bassclient")
    if found:
        yield found
    yield "libbassclient.so.0"  # the SONAME: a runtime-only install has no libbassclient.so link
    yield "libbassclient.so"
    libdir = _pkg_config_libdir()
    if libdir:
        yield os.path.join(libdir, "libbassclient.so")


def _pkg_config_libdir():
    """The libdir pkg-config gives for bassclient, or None (no pkg-config, not installed)."""
    exe = shutil.which("pkg-config")
    if not exe:
        return None
    try:
        out = subprocess.run([exe, "--variable=libdir", "bassclient"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    libdir = out.stdout.strip()
    return libdir if out.returncode == 0 and libdir else None


def _load():
    errors = []
    for path in _candidates():
        if os.sep in path and not os.path.exists(path):
            continue
        try:
            return ctypes.CDLL(path)
        except OSError as e:
            errors.append(f"{path}: {e}")
    raise OSError("libbassclient.so not found (set BASS_LIB): " + "; ".join(errors))


class PortInfo(ctypes.Structure):
    """bass_port_info."""

    _fields_ = [
        ("channels", c_uint32),
        ("sample_rate", c_uint32),
        ("frames_per_chunk", c_uint32),
        ("chunks_on_port", c_uint32),
        ("frames_on_port", c_uint64),
        ("last_frame_index", c_uint64),
        ("epoch", c_uint64),
        ("state", c_uint32),
        ("error_code", c_uint32),
        ("xruns", c_uint64),
        ("gap_frames", c_uint64),
        ("chunks_published", c_uint64),
        ("rate_estimate_hz", c_double),
        ("writer_pid", c_uint32),
        ("writer_alive", c_uint32),
        ("started_mono_ns", c_uint64),
        ("heartbeat_mono_ns", c_uint64),
        ("device", c_char * BASS_DEVICE_LEN),
        ("message", c_char * BASS_MESSAGE_LEN),
        ("lost_upstream_frames", c_uint64),
    ]


class ChunkInfo(ctypes.Structure):
    """bass_chunk_info."""

    _fields_ = [
        ("first_frame", c_uint64),
        ("mono_ns", c_uint64),
        ("realtime_ns", c_uint64),
        ("frames", c_uint32),
        ("flags", c_uint32),
    ]


class ChunkMeta(ctypes.Structure):
    """bass_chunk_meta."""

    _fields_ = [("mono_ns", c_uint64), ("realtime_ns", c_uint64), ("flags", c_uint32)]


class Status(ctypes.Structure):
    """bass_broker_status (the broker's answer to Status)."""

    _fields_ = [
        ("state", c_uint32),
        ("error_code", c_uint32),
        ("sample_rate", c_uint32),
        ("frames_per_chunk", c_uint32),
        ("chunks_on_port", c_uint32),
        ("channels", c_uint32),
        ("epoch", c_uint64),
        ("last_frame_index", c_uint64),
        ("xruns", c_uint64),
        ("gap_frames", c_uint64),
        ("rate_estimate_hz", c_double),
        ("device", c_char * BASS_DEVICE_LEN),
        ("message", c_char * BASS_MESSAGE_LEN),
    ]


class ReplicaInfo(ctypes.Structure):
    """bass_replica_info (a mirror's answer about its replica and the source it follows)."""

    _fields_ = [
        ("link_up", c_uint32),
        ("reserved", c_uint32),
        ("link_since_s", c_double),
        ("source_epoch", c_uint64),
        ("source_last_frame_index", c_uint64),
        ("gap_frames_lost", c_uint64),
        ("gap_frames_source", c_uint64),
        ("outages", c_uint64),
        ("forged_messages", c_uint64),
        ("source", c_char * BASS_DEVICE_LEN),
        ("source_state", c_char * BASS_SOURCE_STATE_LEN),
    ]


class StreamConfig(ctypes.Structure):
    """bass_stream_config (python/bass/stream.py)."""

    _fields_ = [
        ("frames_per_call", c_size_t),
        ("start", c_uint32),
        ("interleaved", c_uint32),
        ("start_frame", c_uint64),
        ("channels", POINTER(c_uint32)),
        ("n_channels", c_size_t),
        ("realtime_priority", ctypes.c_int32),
    ]


class Block(ctypes.Structure):
    """bass_block (one block of a callback stream)."""

    _fields_ = [
        ("epoch", c_uint64),
        ("first_frame", c_uint64),
        ("frames", c_size_t),
        ("lost", c_uint64),
        ("mono_ns", c_uint64),
        ("realtime_ns", c_uint64),
        ("rate_hz", c_double),
        ("flags", c_uint32),
        ("n_channels", c_uint32),
        ("port_channels", POINTER(c_uint32)),
        ("channels", POINTER(POINTER(ctypes.c_int32))),
        ("interleaved", POINTER(ctypes.c_int32)),
    ]


class StreamEvent(ctypes.Structure):
    """bass_stream_event (an event of a callback stream)."""

    _fields_ = [
        ("kind", c_uint32),
        ("code", c_uint32),
        ("epoch", c_uint64),
        ("frame", c_uint64),
        ("os_error", c_int),
        ("message", c_char_p),
    ]


BLOCK_FN = ctypes.CFUNCTYPE(c_int, POINTER(Block), c_void_p)
EVENT_FN = ctypes.CFUNCTYPE(c_int, POINTER(StreamEvent), c_void_p)


lib = _load()
_P = c_void_p
_I32P = POINTER(ctypes.c_int32)

_SIGNATURES = {
    "bass_version": (c_char_p, []),
    "bass_result_str": (c_char_p, [c_int]),
    "bass_result_name": (c_char_p, [c_int]),
    "bass_last_error": (c_char_p, []),
    "bass_state_str": (c_char_p, [c_uint32]),
    "bass_port_open": (c_int, [c_char_p, POINTER(_P)]),
    "bass_port_close": (c_int, [_P]),
    "bass_get_audio_data": (
        c_int,
        [_P, c_size_t, POINTER(c_uint64), _I32P, _I32P, POINTER(c_size_t), POINTER(c_uint64)],
    ),
    "bass_get_audio_data_multi": (
        c_int,
        [_P, c_size_t, POINTER(c_uint64), POINTER(_I32P), c_size_t, POINTER(c_size_t), POINTER(c_uint64)],
    ),
    "bass_port_get_info": (c_int, [_P, POINTER(PortInfo)]),
    "bass_port_wait": (c_int, [_P, c_uint64, c_uint32, POINTER(c_uint64)]),
    "bass_port_chunk_info": (c_int, [_P, c_uint64, POINTER(ChunkInfo)]),
    # name, device, sample_rate, frames_per_chunk, chunks_on_port, channels, out_writer
    "bass_writer_create": (c_int, [c_char_p, c_char_p, c_uint32, c_uint32, c_uint32, c_uint32, POINTER(_P)]),
    "bass_writer_publish_interleaved": (c_int, [_P, _I32P, c_size_t, POINTER(ChunkMeta), POINTER(c_uint64)]),
    "bass_writer_publish_planar": (
        c_int,
        [_P, POINTER(_I32P), c_size_t, c_size_t, POINTER(ChunkMeta), POINTER(c_uint64)],
    ),
    "bass_writer_publish_gap": (c_int, [_P, POINTER(ChunkMeta), POINTER(c_uint64)]),
    "bass_writer_start_at": (c_int, [_P, c_uint64]),
    "bass_writer_publish_lost": (c_int, [_P, c_uint64, POINTER(ChunkMeta), POINTER(c_uint64)]),
    "bass_writer_set_state": (c_int, [_P, c_uint32, c_uint32, c_char_p]),
    "bass_writer_close": (c_int, [_P]),
    # The control plane (present once the broker's client side is in the library).
    "bass_acquire": (c_int, [c_char_p, c_char_p, c_uint32, c_uint32, c_uint32, c_uint32, POINTER(c_uint64)]),
    "bass_stop": (c_int, [c_char_p]),
    "bass_status": (c_int, [c_char_p, POINTER(Status)]),
    "bass_replica_status": (c_int, [c_char_p, POINTER(ReplicaInfo)]),
    "bass_list_devices": (c_int, [c_char_p, POINTER(c_char), c_size_t, POINTER(c_size_t)]),
    # Callback streams (python/bass/stream.py).
    "bass_stream_create": (c_int, [_P, POINTER(StreamConfig), BLOCK_FN, EVENT_FN, c_void_p, POINTER(_P)]),
    "bass_stream_run": (c_int, [_P]),
    "bass_stream_stop": (c_int, [_P]),
    "bass_stream_close": (c_int, [_P]),
}


def _declare():
    missing = []
    for name, (res, args) in _SIGNATURES.items():
        fn = getattr(lib, name, None)
        if fn is None:
            missing.append(name)
            continue
        fn.restype = res
        fn.argtypes = args
    return missing


MISSING = _declare()


def has(name):
    """Whether the loaded library exports `name`."""
    return name not in MISSING
