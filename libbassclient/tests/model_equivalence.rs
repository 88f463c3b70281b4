//! The ring port against a literal model of the seed: two (or more) shifting arrays and
//! the formal `getAudioData` written as in the BASS documentation, with unbounded
//! integers. Random publish sequences and reads (random N; nfr in the past, present and
//! future) must give identical n, nfr, loss and samples.

use bass_test_support::client as common;

use bassport::{ChunkMeta, Geometry, Port, Source};
use common::{temp_port_path, SeedPort};
use proptest::prelude::*;

#[derive(Clone, Debug)]
enum Op {
    /// Publish chunks of random samples (seeded).
    Publish { chunks: usize, seed: u64 },
    /// Read N frames; nfr chosen relative to the model's lastFrameIndex.
    Read { n: usize, nfr: NfrChoice },
}

#[derive(Clone, Debug)]
enum NfrChoice {
    /// lfi - back (saturating at 0): in the past, possibly lost.
    Past(u64),
    /// lfi or lfi + 1.
    Present(bool),
    /// lfi + 1 + ahead.
    Future(u64),
    /// Continue from the previous read's nfr.
    Continue,
}

fn op(nfop: usize) -> impl Strategy<Value = Op> {
    let n = prop_oneof![0..=nfop + 2, Just(nfop), Just(nfop + 1), 0..=3 * nfop + 5];
    let nfr = prop_oneof![
        (0..=(3 * nfop as u64 + 3)).prop_map(NfrChoice::Past),
        any::<bool>().prop_map(NfrChoice::Present),
        (0..=(nfop as u64 + 3)).prop_map(NfrChoice::Future),
        Just(NfrChoice::Continue),
        Just(NfrChoice::Continue),
    ];
    prop_oneof![
        (1..=3usize, any::<u64>()).prop_map(|(chunks, seed)| Op::Publish { chunks, seed }),
        (n, nfr).prop_map(|(n, nfr)| Op::Read { n, nfr }),
    ]
}

fn scenario() -> impl Strategy<Value = (u32, u32, u32, Vec<Op>)> {
    (1u32..=4, 1u32..=6, prop_oneof![Just(1u32), Just(2), Just(2), Just(3), Just(8)]).prop_flat_map(
        |(nfpc, ncop, channels)| {
            let nfop = (nfpc * ncop) as usize;
            (Just(nfpc), Just(ncop), Just(channels), proptest::collection::vec(op(nfop), 1..80))
        },
    )
}

fn chunk_samples(seed: u64, len: usize) -> Vec<i32> {
    // Any deterministic, varied content will do.
    let mut rng = fastrand::Rng::with_seed(seed);
    (0..len).map(|_| rng.i32(..)).collect()
}

fn run(nfpc: u32, ncop: u32, channels: u32, ops: &[Op]) -> Result<(), TestCaseError> {
    let path = temp_port_path("model");
    let geometry = Geometry { channels, sample_rate: 48000, frames_per_chunk: nfpc, chunks_on_port: ncop };
    let params = bassport::PortParams { geometry, device: "model".into(), group: None };
    let mut writer = bassport::Writer::create_at(&path, &params).expect("create port");
    let port = Port::open_path(&path).expect("open port");
    let mut model = SeedPort::new(nfpc as usize, ncop as usize, channels as usize);
    let nfop = (nfpc * ncop) as usize;
    let mut cont: u64 = 0;
    for op in ops {
        match op {
            Op::Publish { chunks, seed } => {
                for k in 0..*chunks {
                    let s = chunk_samples(seed.wrapping_add(k as u64), nfpc as usize * channels as usize);
                    writer.publish(Source::Interleaved(&s), ChunkMeta::default()).expect("publish");
                    model.publish_interleaved(&s);
                }
            }
            Op::Read { n, nfr } => {
                let lfi = model.last_frame_index as u64;
                let start = match nfr {
                    NfrChoice::Past(back) => lfi.saturating_sub(*back),
                    NfrChoice::Present(next) => lfi + u64::from(*next),
                    NfrChoice::Future(ahead) => lfi + 1 + ahead,
                    NfrChoice::Continue => cont,
                };
                let expected = model.get_audio_data(*n as i128, start as i128);
                let mut bufs = vec![vec![i32::MIN; (*n).min(nfop)]; channels as usize];
                let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
                let mut got_nfr = start;
                let r = port.get_audio_data(*n, &mut got_nfr, &mut outs).expect("read");
                prop_assert_eq!(r.frames as i128, expected.n, "n for N={} nfr={} lfi={}", n, start, lfi);
                prop_assert_eq!(got_nfr as i128, expected.nfr, "nfr");
                prop_assert_eq!(r.loss as i128, expected.loss, "loss");
                for (c, (got, want)) in bufs.iter().zip(&expected.channels).enumerate() {
                    prop_assert_eq!(&got[..r.frames], &want[..], "channel {} samples", c);
                }
                cont = got_nfr;
            }
        }
    }
    drop(port);
    writer.remove().expect("remove port");
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn ring_port_reads_exactly_like_the_seed_model((nfpc, ncop, channels, ops) in scenario()) {
        run(nfpc, ncop, channels, &ops)?;
    }
}

#[test]
fn zero_frame_before_any_data_reads_as_zero() {
    // lfi = 0: ofi = 0, so frame 0 is "on the port" and reads as one zero frame.
    let path = temp_port_path("zero");
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: 4, chunks_on_port: 3 };
    let params = bassport::PortParams { geometry, device: String::new(), group: None };
    let writer = bassport::Writer::create_at(&path, &params).unwrap();
    let port = Port::open_path(&path).unwrap();
    let (mut l, mut r) = (vec![7; 12], vec![7; 12]);
    let mut nfr = 0;
    let got = port.get_audio_data(12, &mut nfr, &mut [&mut l, &mut r]).unwrap();
    assert_eq!((got.frames, got.loss, nfr), (1, 0, 1));
    assert_eq!((l[0], r[0]), (0, 0));
    // nfr = 1 is in the future: n = 0, nfr unchanged.
    let got = port.get_audio_data(12, &mut nfr, &mut [&mut l, &mut r]).unwrap();
    assert_eq!((got.frames, got.loss, nfr), (0, 0, 1));
    writer.remove().unwrap();
}

#[test]
fn loss_moves_nfr_to_the_oldest_frame_on_the_port() {
    let path = temp_port_path("loss");
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: 2, chunks_on_port: 3 };
    let params = bassport::PortParams { geometry, device: String::new(), group: None };
    let mut writer = bassport::Writer::create_at(&path, &params).unwrap();
    let port = Port::open_path(&path).unwrap();
    for _ in 0..5 {
        let mut s = vec![0; 4];
        basskit::testsignal::fill_pattern_interleaved(&mut s, 2, writer.last_frame_index() + 1);
        writer.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    }
    // lfi = 10, nFOP = 6: the port holds frames 5..=10.
    let (mut l, mut r) = (vec![0; 100], vec![0; 100]);
    let mut nfr = 2;
    let got = port.get_audio_data(100, &mut nfr, &mut [&mut l, &mut r]).unwrap();
    assert_eq!((got.frames, got.loss, nfr), (6, 3, 11));
    for i in 0..6 {
        assert_eq!(l[i], basskit::testsignal::pattern_sample(5 + i as u64, 0));
        assert_eq!(r[i], basskit::testsignal::pattern_sample(5 + i as u64, 1));
    }
    writer.remove().unwrap();
}
