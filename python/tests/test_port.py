"""The Python client against real ports made by the writer C ABI (no broker needed)."""

import threading

import numpy as np
import pytest

import bass


def pattern_chunk(first, frames, channels=2):
    f = np.arange(first, first + frames, dtype=np.uint64)
    return np.stack([bass.pattern_expected(f, c) for c in range(channels)], axis=1)


def publish_chunks(w, lfi, count, fpc):
    for _ in range(count):
        lfi = w.publish(pattern_chunk(lfi + 1, fpc))
    return lfi


def test_fresh_port_reads_the_zero_frame_then_nothing():
    with bass.Writer("p", frames_per_chunk=4, chunks_on_port=3), bass.Port("p") as port:
        d = port.get_audio_data(5, 0)
        assert (d.n, d.nfr, d.loss) == (1, 1, 0)
        assert d.left.tolist() == [0] and d.right.tolist() == [0]
        assert port.get_audio_data(5, 1).n == 0


@pytest.mark.parametrize("positional", [False, True])
def test_writer_geometry_reaches_the_port_in_acquires_order(positional):
    # sample_rate, frames_per_chunk, chunks_on_port, channels: the order of bass.acquire and of
    # bass_writer_create; four distinct values, so a swap anywhere on the way shows.
    geometry = dict(sample_rate=22050, frames_per_chunk=5, chunks_on_port=7, channels=3)
    w = bass.Writer("g", *geometry.values()) if positional else bass.Writer("g", **geometry)
    with w, bass.Port("g") as port:
        i = port.info()
        assert {k: i[k] for k in geometry} == geometry
        assert i["frames_on_port"] == 35
        chunk = pattern_chunk(1, 5, channels=3)
        w.publish(chunk)
        x, nfr, n, loss = port.get_audio_data_multi(5, 1)
        assert (n, nfr, loss) == (5, 6, 0)
        assert x.T.tolist() == chunk.tolist()


def test_get_audio_data_returns_int32_columns_of_the_published_frames():
    with bass.Writer("p", frames_per_chunk=4, chunks_on_port=3) as w, bass.Port("p") as port:
        publish_chunks(w, 0, 2, 4)
        d = port.get_audio_data(6, 2)
        assert d.left.dtype == np.int32 and d.right.dtype == np.int32
        assert (d.n, d.nfr, d.loss) == (6, 8, 0)
        np.testing.assert_array_equal(d.left, bass.pattern_expected(np.arange(2, 8), 0))
        np.testing.assert_array_equal(d.right, bass.pattern_expected(np.arange(2, 8), 1))


def test_partial_read_when_the_block_reaches_past_the_newest_frame():
    with bass.Writer("p", frames_per_chunk=4, chunks_on_port=3) as w, bass.Port("p") as port:
        publish_chunks(w, 0, 1, 4)
        d = port.get_audio_data(10, 3)
        assert (d.n, d.nfr, d.loss) == (2, 5, 0)
        d = port.get_audio_data(10, 9)
        assert (d.n, d.nfr, d.loss) == (0, 9, 0)


def test_loss_moves_nfr_to_the_oldest_frame_and_counts_the_gap():
    with bass.Writer("p", frames_per_chunk=4, chunks_on_port=3) as w, bass.Port("p") as port:
        publish_chunks(w, 0, 5, 4)  # lfi 20, window 9..20
        d = port.get_audio_data(3, 2)
        assert (d.n, d.nfr, d.loss) == (3, 12, 7)
        np.testing.assert_array_equal(d.left, bass.pattern_expected(np.arange(9, 12), 0))


def test_blocks_are_consecutive_while_a_writer_publishes():
    fpc, cop = 64, 8
    with bass.Writer("p", frames_per_chunk=fpc, chunks_on_port=cop) as w, bass.Port("p") as port:
        stop = threading.Event()

        def produce():
            lfi = 0
            for _ in range(400):
                if stop.is_set():
                    break
                lfi = publish_chunks(w, lfi, 1, fpc)
                stop.wait(0.002)

        t = threading.Thread(target=produce)
        t.start()
        try:
            expect = None
            blocks = list(port.blocks(100, nfr=1, count=50, timeout=10))
        finally:
            stop.set()
            t.join()
        for b in blocks:
            if expect is not None and b.loss == 0:
                assert b.first_frame == expect
            expect = b.next_frame
            if b.loss == 0:
                frames = np.arange(b.first_frame, b.first_frame + 100)
                np.testing.assert_array_equal(b.left, bass.pattern_expected(frames, 0))
                np.testing.assert_array_equal(b.right, bass.pattern_expected(frames, 1))
        # Every frame from 1 on was either delivered or counted as lost.
        assert blocks[0].loss > 0 or blocks[0].first_frame == 1
        assert sum(100 + b.loss for b in blocks) == blocks[-1].next_frame - 1


def test_wait_returns_the_last_frame_index_and_times_out_with_its_code():
    with bass.Writer("p", frames_per_chunk=4, chunks_on_port=3) as w, bass.Port("p") as port:
        publish_chunks(w, 0, 1, 4)
        assert port.wait(3, timeout=1) == 4
        with pytest.raises(bass.BassError) as e:
            port.wait(5, timeout=0.05)
        assert e.value.code == bass.BASS_ERR_TIMEOUT and e.value.name == "TIMEOUT"


def test_wait_raises_stopped_when_the_writer_closes():
    w = bass.Writer("p", frames_per_chunk=4, chunks_on_port=3)
    with bass.Port("p") as port:
        w.close()
        with pytest.raises(bass.BassError) as e:
            port.wait(1, timeout=1)
        assert e.value.code == bass.BASS_ERR_STOPPED


def test_opening_a_missing_port_raises_not_found_with_the_library_message():
    with pytest.raises(bass.BassError) as e:
        bass.Port("nothing-here")
    assert e.value.code == bass.BASS_ERR_NOT_FOUND
    assert "nothing-here" in e.value.message


def test_multi_channel_read_returns_every_channel():
    with bass.Writer("p", channels=4, frames_per_chunk=4, chunks_on_port=3) as w, bass.Port("p") as port:
        w.publish(pattern_chunk(1, 4, channels=4))
        data, nfr, n, loss = port.get_audio_data_multi(4, 1)
        assert (nfr, n, loss) == (5, 4, 0) and data.shape == (4, 4)
        for c in range(4):
            np.testing.assert_array_equal(data[c], bass.pattern_expected(np.arange(1, 5), c))


def test_blocks_longer_than_the_window_are_assembled_with_exact_accounting():
    # The producer is paced, not throttled by the reader, so a starved reader may lose frames:
    # the test asserts the accounting of every block and the samples of every loss-free one
    # (a block is only delivered whole: 1500 frames, after `loss` frames that left the window).
    fpc, cop = 64, 8  # nFOP = 512 frames, blocks of 1500
    with bass.Writer("p", frames_per_chunk=fpc, chunks_on_port=cop) as w, bass.Port("p") as port:
        stop = threading.Event()

        def produce():
            lfi = 0
            while not stop.is_set() and lfi < 64 * 200:
                lfi = publish_chunks(w, lfi, 1, fpc)
                stop.wait(0.004)  # 16 frames/ms: the reader must come back within 16 ms

        t = threading.Thread(target=produce)
        t.start()
        try:
            blocks = list(port.blocks(1500, nfr=1, count=4, timeout=10))
        finally:
            stop.set()
            t.join()
        assert sum(1500 + b.loss for b in blocks) == blocks[-1].next_frame - 1
        assert any(b.loss == 0 for b in blocks), "no block was assembled without loss"
        for b in blocks:
            if b.loss == 0:
                frames = np.arange(b.first_frame, b.next_frame)
                assert len(frames) == 1500
                np.testing.assert_array_equal(b.left, bass.pattern_expected(frames, 0))


def test_chunk_info_names_the_flags_and_carries_the_timestamps_the_writer_gave():
    with bass.Writer("ci", frames_per_chunk=4, chunks_on_port=3) as w, bass.Port("ci") as port:
        w.publish(pattern_chunk(1, 4), flags=bass.CHUNK_LATE | bass.CHUNK_TIME_ESTIMATED, mono_ns=111,
                  realtime_ns=222)
        w.publish_gap(flags=bass.CHUNK_DISCONTINUITY)
        w.publish(pattern_chunk(9, 4))
        late = port.chunk_info(4)
        assert (late.first_frame, late.frames, late.mono_ns, late.realtime_ns) == (1, 4, 111, 222)
        assert late.flag_names == ("TIME_ESTIMATED", "LATE")
        gap = port.chunk_info(5)
        assert gap.first_frame == 5 and gap.flag_names == ("GAP", "DISCONTINUITY")
        assert gap.flags == bass.CHUNK_GAP | bass.CHUNK_DISCONTINUITY
        plain = port.chunk_info(12)
        assert plain.flag_names == () and plain.mono_ns > 0  # 0 given: stamped now
        with pytest.raises(bass.BassError) as e:
            port.chunk_info(13)
        assert e.value.name == "FRAME_NOT_YET"
        w.publish(pattern_chunk(13, 4))
        with pytest.raises(bass.BassError) as e:
            port.chunk_info(4)  # chunk 0 left the 3-chunk window
        assert e.value.name == "FRAME_LOST"
        with pytest.raises(ValueError):
            port.chunk_info(-1)


def test_info_has_every_field_and_a_replica_shows_what_was_lost_upstream():
    with bass.Writer("rep", frames_per_chunk=4, chunks_on_port=3) as w, bass.Port("rep") as port:
        w.start_at(9)
        w.publish(pattern_chunk(9, 4))
        assert w.publish_lost(8) == 20
        i = port.info()
        assert set(i) >= {name for name, _ in bass._lib.PortInfo._fields_}
        assert (i["lost_upstream_frames"], i["gap_frames"], i["last_frame_index"]) == (8, 8, 20)
        assert i["started_mono_ns"] > 0 and i["heartbeat_mono_ns"] >= i["started_mono_ns"]
        assert port.chunk_info(20).flag_names == ("GAP",)
        d = port.get_audio_data(12, 1)
        assert (d.n, d.loss, d.nfr) == (12, 8, 21)  # frames 1..8 this port never had: lost
        assert not d.left[4:].any()  # 13..20: zero-filled GAP frames
