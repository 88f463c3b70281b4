"""iceoryx2 subscriber of `bass-bridge serve --iceoryx2` (PyPI iceoryx2, same version as the
crate): receives chunks from `bass/<broker>/chunks` and checks the frame indices (consecutive
chunks) and every sample against the pattern signal. Prints one line; exit 1 on a mismatch.

usage: iox_subscriber.py BROKER CHUNKS TIMEOUT_S
"""

import ctypes
import sys
import time

import iceoryx2 as iox2


class ChunkHeader(ctypes.Structure):
    """bridge/src/iox.rs ChunkHeader (repr(C), 112 bytes, version 3)."""

    _fields_ = [(n, ctypes.c_uint64) for n in (
        "instance", "epoch", "sequence", "first_frame", "mono_ns", "realtime_ns", "send_mono_ns",
        "source_lost")] + [(n, ctypes.c_uint32) for n in (
        "version", "flags", "frames", "channels", "sample_rate", "chunks_on_port")] + [
        (n, ctypes.c_uint64) for n in ("bound_ns", "missing_channels", "unaligned_channels")]

    @staticmethod
    def type_name():
        return "BassChunkHeader"


def pattern(frame, channel):
    v = (((frame & 0x3FFFFFF) << 6) | (channel & 63)) & 0xFFFFFFFF
    return v - (1 << 32) if v >= (1 << 31) else v


def main():
    broker, want, timeout = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    assert ctypes.sizeof(ChunkHeader) == 112
    node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
    service = (node.service_builder(iox2.ServiceName.new(f"bass/{broker}/chunks"))
               .publish_subscribe(iox2.Slice[ctypes.c_int32]).user_header(ChunkHeader).open_or_create())
    sub = service.subscriber_builder().create()
    got, bad, gaps, expected, bounded, masked, versions = 0, 0, 0, None, 0, 0, set()
    deadline = time.monotonic() + timeout
    while got < want and time.monotonic() < deadline:
        sample = sub.receive()
        if sample is None:
            time.sleep(0.002)
            continue
        h = sample.user_header().contents
        payload = sample.payload()
        n = h.frames * h.channels
        # Slice.len() counts bytes in this package version.
        assert payload.len() in (n, 4 * n), (payload.len(), n)
        if expected is not None and h.first_frame != expected:
            gaps += 1
        expected = h.first_frame + h.frames
        versions.add(h.version)
        # bassd bounds every chunk's stamp (a-priori at first); a stereo sim card has no followers.
        bounded += h.bound_ns != (1 << 64) - 1 and h.bound_ns > 0
        masked += h.missing_channels != 0 or h.unaligned_channels != 0
        for i in range(n):
            f, c = h.first_frame + i // h.channels, i % h.channels
            if payload[i] != pattern(f, c):
                bad += 1
        got += 1
    print(f"iceoryx2: {got} chunks, {bad} wrong samples, {gaps} index jumps, {bounded} with a "
          f"timestamp bound, {masked} with channel masks, header versions {sorted(versions)}")
    del sub, service, node
    sys.exit(0 if got == want and bad == 0 and bounded == got and masked == 0 and versions == {3} else 1)


main()
