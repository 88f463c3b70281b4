"""Port.blocks() reads every channel of a port, 1 to 64: 1 channel used to
raise a C-function-name error, 4 channels silently dropped two."""

import numpy as np
import pytest

import bass


@pytest.mark.parametrize("channels", [1, 2, 4, 64])
def test_blocks_read_every_channel(clients_env, channels):
    name = f"blocks-ch{channels}"
    nfpc = 16
    with bass.Writer(name, channels=channels, sample_rate=8000, frames_per_chunk=nfpc, chunks_on_port=8) as w:
        for k in range(4):
            frames = np.arange(k * nfpc + 1, (k + 1) * nfpc + 1, dtype=np.uint64)
            w.publish(np.stack([bass.pattern_expected(frames, c) for c in range(channels)], axis=1))
        with bass.Port(name) as p:
            blocks = list(p.blocks(24, nfr=1, count=2, timeout=5))
    assert [(b.first_frame, b.next_frame, b.loss) for b in blocks] == [(1, 25, 0), (25, 49, 0)]
    for b in blocks:
        data = bass.Port.block_samples(b)
        assert data.shape == (channels, 24)
        frames = np.arange(b.first_frame, b.next_frame, dtype=np.uint64)
        for c in range(channels):
            assert np.array_equal(data[c], bass.pattern_expected(frames, c)), f"channel {c}"
        assert np.array_equal(b.left, data[0])
        assert (b.right is None) if channels == 1 else np.array_equal(b.right, data[1])
