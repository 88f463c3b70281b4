//! The replica additions of the writer (`start_at`, `publish_lost`): a port that follows
//! another port's frame indices and marks what was lost on the way, held against the
//! literal seed model (a lost run = that many zero frames published in the model).

use bass_test_support::client as common;

use basskit::testsignal::{fill_pattern_interleaved, pattern_expected};
use bassport::format::chunk_flags;
use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
use common::{temp_port_path, SeedPort};
use proptest::prelude::*;

fn params(nfpc: u32, ncop: u32, channels: u32) -> PortParams {
    PortParams {
        geometry: Geometry { channels, sample_rate: 48000, frames_per_chunk: nfpc, chunks_on_port: ncop },
        device: "replica".into(),
        group: None,
    }
}

fn pattern_chunk(w: &Writer) -> Vec<i32> {
    let g = w.geometry();
    let mut s = vec![0; (g.frames_per_chunk * g.channels) as usize];
    fill_pattern_interleaved(&mut s, g.channels, w.last_frame_index() + 1);
    s
}

#[test]
fn a_port_started_at_a_frame_publishes_its_first_chunk_at_that_index() {
    let path = temp_port_path("start-at");
    let mut w = Writer::create_at(&path, &params(4, 3, 2)).unwrap();
    w.start_at(1_000_001).unwrap();
    let port = Port::open_path(&path).unwrap();
    assert_eq!(port.info().unwrap().last_frame_index, 1_000_000);
    let s = pattern_chunk(&w);
    assert_eq!(w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap(), 1_000_004);
    let (mut l, mut r) = (vec![0; 4], vec![0; 4]);
    let mut nfr = 1_000_001;
    let got = port.get_audio_data(4, &mut nfr, &mut [&mut l, &mut r]).unwrap();
    assert_eq!((got.frames, got.loss, nfr), (4, 0, 1_000_005));
    for i in 0..4 {
        assert_eq!(l[i], pattern_expected(1_000_001 + i as u64, 0));
        assert_eq!(r[i], pattern_expected(1_000_001 + i as u64, 1));
    }
    assert_eq!(port.chunk_info(1_000_002).unwrap().first_frame, 1_000_001);
    w.remove().unwrap();
}

/// Reads up to `n` frames from `nfr` on a 2-channel port; returns (frames, loss, nfr, left).
fn read2(port: &Port, n: usize, mut nfr: u64) -> (usize, u64, u64, Vec<i32>) {
    let (mut l, mut r) = (vec![i32::MIN; n], vec![i32::MIN; n]);
    let got = port.get_audio_data(n, &mut nfr, &mut [&mut l, &mut r]).unwrap();
    for (i, (a, b)) in l.iter().zip(&r).take(got.frames).enumerate() {
        let f = nfr - got.frames as u64 + i as u64;
        assert_eq!((*a, *b), (pattern_expected(f, 0), pattern_expected(f, 1)), "frame {f}");
    }
    l.truncate(got.frames);
    (got.frames, got.loss, nfr, l)
}

/// (frames, loss, nfr) of a [`read2`].
fn nln(r: (usize, u64, u64, Vec<i32>)) -> (usize, u64, u64) {
    (r.0, r.1, r.2)
}

/// A replica started at frame F never presents frames 1..F-1 (which it never
/// had) as zero audio; every read path counts them as lost until the window has passed F.
#[test]
fn frames_before_a_replica_start_are_lost_not_zeros() {
    let path = temp_port_path("start-at-loss");
    // nFOP = 12; the replica starts at frame 9 (chunk 3).
    let mut w = Writer::create_at(&path, &params(4, 3, 2)).unwrap();
    let port = Port::open_path(&path).unwrap();
    w.start_at(9).unwrap();
    // Nothing published: frames 1..=8 are on the window by the formal algorithm (ofi = 0)
    // but were never written: all lost, nfr moves to the start.
    assert_eq!(nln(read2(&port, 12, 1)), (0, 8, 9));
    assert_eq!(nln(read2(&port, 12, 0)), (0, 9, 9), "frame 0 too is before the start");
    assert_eq!(nln(read2(&port, 12, 5)), (0, 4, 9));
    let v = port.view(12, &mut 1).unwrap();
    assert_eq!((v.first_frame, v.frames, port.view_overwritten(&v)), (1, 8, 8));
    // Frames 9..=12 published: a reader at 1 gets loss 8, then the real frames.
    let s = pattern_chunk(&w);
    w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    let (n, loss, nfr, _) = read2(&port, 12, 1);
    assert_eq!((n, loss, nfr), (4, 8, 13));
    assert!(port.chunk_info(5).is_err(), "chunk info of a frame before the start");
    assert_eq!(port.chunk_info(9).unwrap().first_frame, 9);
    // Frames 13..=16: the window (5..=16) still holds frames before the start.
    let s = pattern_chunk(&w);
    w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    assert_eq!(nln(read2(&port, 12, 1)), (8, 8, 17));
    // A short read wholly before the start: n = 0, nfr moves to the start.
    assert_eq!(nln(read2(&port, 3, 6)), (0, 3, 9));
    let mut nfr = 1;
    let v = port.view(12, &mut nfr).unwrap();
    assert_eq!((v.first_frame, v.frames, v.loss, port.view_overwritten(&v)), (5, 12, 4, 4));
    // Frames 17..=24: the window passes the floor (20) and moves on as any window.
    for _ in 0..2 {
        let s = pattern_chunk(&w);
        w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    }
    let (n, loss, nfr, _) = read2(&port, 12, 1);
    assert_eq!((n, loss, nfr), (12, 12, 25));
    let (n, loss, nfr, _) = read2(&port, 12, 13);
    assert_eq!((n, loss, nfr), (12, 0, 25));
    w.remove().unwrap();
}

/// A gap published right after the start (chunk by chunk, and longer than the window) keeps
/// the accounting: frames before the start lost, GAP frames read as GAP zeros.
#[test]
fn a_started_replica_with_lost_runs_still_counts_frames_before_its_start_as_lost() {
    let path = temp_port_path("start-at-gap");
    let mut w = Writer::create_at(&path, &params(4, 3, 2)).unwrap();
    let port = Port::open_path(&path).unwrap();
    w.start_at(5).unwrap();
    w.publish_lost(4, ChunkMeta::default()).unwrap(); // frames 5..=8, GAP
    let (mut l, mut r) = (vec![9; 12], vec![9; 12]);
    let mut nfr = 1;
    let got = port.get_audio_data(12, &mut nfr, &mut [&mut l, &mut r]).unwrap();
    assert_eq!((got.frames, got.loss, nfr), (4, 4, 9));
    assert!(l[..4].iter().chain(&r[..4]).all(|&x| x == 0));
    // A run longer than the window jumps: the floor is below its end.
    assert_eq!(w.publish_lost(40, ChunkMeta::default()).unwrap(), 48);
    let s = pattern_chunk(&w);
    w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    let got = port.get_audio_data(12, &mut nfr, &mut [&mut l, &mut r]).unwrap();
    assert_eq!((got.frames, got.loss, nfr), (12, 32, 53));
    assert_eq!(l[8], pattern_expected(49, 0));
    w.remove().unwrap();
}

#[test]
fn start_at_refuses_a_frame_inside_a_chunk_and_a_port_with_data() {
    let path = temp_port_path("start-at-bad");
    let mut w = Writer::create_at(&path, &params(4, 3, 1)).unwrap();
    for bad in [0, 2, 4, 1_000_000] {
        assert!(w.start_at(bad).is_err(), "start_at({bad}) must be refused");
    }
    w.start_at(9).unwrap();
    let s = pattern_chunk(&w);
    w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    assert!(w.start_at(13).is_err(), "start_at after a publish must be refused");
    w.remove().unwrap();
}

#[test]
fn lost_frames_are_zero_gap_chunks_counted_as_gap_and_lost_upstream() {
    let path = temp_port_path("lost");
    let mut w = Writer::create_at(&path, &params(4, 3, 2)).unwrap();
    let port = Port::open_path(&path).unwrap();
    let s = pattern_chunk(&w);
    w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    assert!(w.publish_lost(3, ChunkMeta::default()).is_err(), "a part of a chunk is refused");
    assert_eq!(w.publish_lost(8, ChunkMeta::default()).unwrap(), 12);
    let info = port.info().unwrap();
    assert_eq!((info.gap_frames, info.lost_upstream_frames, info.chunks_published), (8, 8, 3));
    let c = port.chunk_info(6).unwrap();
    assert_eq!((c.first_frame, c.flags & chunk_flags::GAP), (5, chunk_flags::GAP));
    let (mut l, mut r) = (vec![9; 12], vec![9; 12]);
    let mut nfr = 1;
    let got = port.get_audio_data(12, &mut nfr, &mut [&mut l, &mut r]).unwrap();
    assert_eq!((got.frames, got.loss, nfr), (12, 0, 13));
    assert_eq!(l[3], pattern_expected(4, 0));
    assert!(l[4..].iter().chain(&r[4..]).all(|&x| x == 0));
    w.remove().unwrap();
}

#[test]
fn a_lost_run_longer_than_the_window_jumps_and_a_lapped_reader_counts_it_as_loss() {
    let path = temp_port_path("lost-long");
    let mut w = Writer::create_at(&path, &params(4, 3, 1)).unwrap();
    let port = Port::open_path(&path).unwrap();
    for _ in 0..3 {
        let s = pattern_chunk(&w);
        w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    }
    // 1000 chunks lost: one window of writes, indices jump to 12 + 4000.
    assert_eq!(w.publish_lost(4000, ChunkMeta::default()).unwrap(), 4012);
    let s = pattern_chunk(&w);
    w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    let info = port.info().unwrap();
    assert_eq!((info.gap_frames, info.lost_upstream_frames), (4000, 4000));
    let mut out = vec![7; 12];
    let mut nfr = 5;
    let got = port.get_audio_data(12, &mut nfr, &mut [&mut out]).unwrap();
    // The port holds 4005..=4016: 4000 frames lost to this reader, 8 zeros, then the pattern.
    assert_eq!((got.frames, got.loss, nfr), (12, 4000, 4017));
    assert!(out[..8].iter().all(|&x| x == 0));
    assert_eq!(out[8], pattern_expected(4013, 0));
    assert_eq!(port.chunk_info(4005).unwrap().first_frame, 4005);
    assert_eq!(port.chunk_info(4005).unwrap().flags & chunk_flags::GAP, chunk_flags::GAP);
    w.remove().unwrap();
}

#[derive(Clone, Debug)]
enum Op {
    Publish,
    Lost(u64),
    Read(usize, u64),
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, failure_persistence: None, ..ProptestConfig::default() })]

    /// Any mix of data chunks and lost runs (short or longer than the window) after a start at
    /// any chunk reads exactly like the seed model in which a lost run is that many zero frames,
    /// except that frames before the start, zero frames in the model, are counted as lost.
    #[test]
    fn replica_writes_read_like_the_seed_model_with_frames_before_the_start_lost(
        nfpc in 1u32..=4, ncop in 1u32..=4, start_chunk in 0u64..5,
        ops in proptest::collection::vec(prop_oneof![
            Just(Op::Publish),
            (1u64..=10).prop_map(Op::Lost),
            (0usize..=20, 0u64..=30).prop_map(|(n, back)| Op::Read(n, back)),
        ], 1..40),
    ) {
        let path = temp_port_path("replica-model");
        let mut w = Writer::create_at(&path, &params(nfpc, ncop, 2)).unwrap();
        let port = Port::open_path(&path).unwrap();
        let mut model = SeedPort::new(nfpc as usize, ncop as usize, 2);
        let first = start_chunk * u64::from(nfpc) + 1;
        if start_chunk > 0 {
            w.start_at(first).unwrap();
        }
        let zeros = vec![0; 2 * nfpc as usize];
        // The model starts at frame 1: its frames before `first` are zero frames too.
        for _ in 0..start_chunk { model.publish_interleaved(&zeros); }
        let mut lost = 0;
        for op in &ops {
            match op {
                Op::Publish => {
                    let s = pattern_chunk(&w);
                    w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
                    model.publish_interleaved(&s);
                }
                Op::Lost(chunks) => {
                    w.publish_lost(chunks * u64::from(nfpc), ChunkMeta::default()).unwrap();
                    for _ in 0..*chunks { model.publish_interleaved(&zeros); }
                    lost += chunks * u64::from(nfpc);
                }
                Op::Read(n, back) => {
                    let lfi = w.last_frame_index();
                    // Readers start anywhere, also before the replica's first frame.
                    let start = lfi.saturating_sub(*back);
                    let mut want = model.get_audio_data(*n as i128, start as i128);
                    // The model's frames before `first` are zero frames the replica never had:
                    // a started replica counts them as lost instead. A port
                    // not started keeps frame 0, the zero frame of the formal algorithm.
                    let model_first = want.nfr - want.n;
                    let lost_from = if start_chunk > 0 { first as i128 } else { 0 };
                    let before = (lost_from - model_first).clamp(0, want.n);
                    want.n -= before;
                    want.loss += before;
                    for ch in &mut want.channels {
                        ch.drain(..before as usize);
                    }
                    // A read whose frames all lie before the start reports the whole run up to
                    // the start as one loss (the loss is not cut into blocks of `n`, as in the
                    // formal algorithm's `ofi - nfr`): `nfr` moves to the start.
                    if before > 0 && want.n == 0 && want.nfr < lost_from {
                        want.loss += lost_from - want.nfr;
                        want.nfr = lost_from;
                    }
                    let mut bufs = vec![vec![i32::MIN; *n]; 2];
                    let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
                    let mut nfr = start;
                    let r = port.get_audio_data(*n, &mut nfr, &mut outs).unwrap();
                    prop_assert_eq!(r.frames as i128, want.n);
                    prop_assert_eq!(nfr as i128, want.nfr);
                    prop_assert_eq!(r.loss as i128, want.loss);
                    for (got, exp) in bufs.iter().zip(&want.channels) {
                        prop_assert_eq!(&got[..r.frames], &exp[..]);
                    }
                }
            }
        }
        prop_assert_eq!(port.info().unwrap().lost_upstream_frames, lost);
        w.remove().unwrap();
    }
}
