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


# The constants and structs of include/bass.h, generated from the library's sources.
from ._abi import (  # noqa: F401  (re-exported: the package and its tests use _lib's names)
    BASS_BOUND_UNKNOWN,
    BASS_DEVICE_LEN,
    BASS_MESSAGE_LEN,
    BASS_SOURCE_STATE_LEN,
    BASS_WAIT_FOREVER,
    BLOCK_FN,
    CHUNK_FLAGS,
    EVENT_FN,
    SIGNATURES,
    Block,
    ChunkExt,
    ChunkInfo,
    ChunkMeta,
    DeviceInfo,
    PortInfo,
    ReplicaInfo,
    Status,
    StreamConfig,
    StreamEvent,
)


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


lib = _load()


def _declare():
    missing = []
    for name, (res, args) in SIGNATURES.items():
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
