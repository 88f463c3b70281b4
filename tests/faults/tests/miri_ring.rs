//! Item 12 — the window protocol (`bassport::ring::Ring`) on heap memory, for Miri.
//!
//! One writer thread publishes the pattern signal into a small heap-backed ring while two
//! reader threads read it with the same code the port reader uses. Pass: no sample is ever
//! corrupted and per reader delivered + lost = requested exactly. Under Miri
//! (`cargo +nightly miri test -p bass-faults --test miri_ring`, run by run.sh when
//! the toolchain has Miri) this also checks the protocol for undefined behaviour, data
//! races and out-of-bounds accesses, with Miri's weak-memory emulation exploring stale
//! loads. Also runs as a plain test (more chunks) in `cargo test`.

use std::sync::atomic::{AtomicU64, Ordering};

use basskit::testsignal::{fill_pattern_interleaved, pattern_expected};
use bassport::ring::{Ring, Source};

const CH: usize = 2;
const NFPC: usize = 4;
const NCOP: usize = 3;
const NFOP: usize = NFPC * NCOP;

#[test]
fn heap_ring_readers_never_see_torn_frames_and_account_every_frame() {
    let chunks: u64 = if cfg!(miri) { 60 } else { 20_000 };
    let lfi = AtomicU64::new(0);
    let intent = AtomicU64::new(0);
    let samples: Vec<AtomicU64> = (0..(CH * NFOP).div_ceil(2)).map(|_| AtomicU64::new(0)).collect();
    let ring = Ring {
        last_frame_index: &lfi,
        write_intent: &intent,
        samples: &samples,
        frames_on_port: NFOP as u64,
    };
    let last = chunks * NFPC as u64;
    let start = std::sync::Barrier::new(3);
    let results = std::thread::scope(|s| {
        let readers: Vec<_> = [1usize, 5]
            .into_iter()
            .map(|n| {
                let (ring, start) = (&ring, &start);
                s.spawn(move || {
                    start.wait();
                    let mut bufs = vec![vec![0i32; n]; CH];
                    let (mut nfr, mut delivered, mut lost, mut corrupted) = (1u64, 0u64, 0u64, 0u64);
                    while nfr <= last {
                        let l = ring.last_frame_index.load(Ordering::Acquire);
                        let before = nfr;
                        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
                        let r = ring.read(l, n, nfr, &mut outs);
                        nfr = r.next_frame;
                        let first = before + r.loss;
                        for (c, b) in bufs.iter().enumerate() {
                            for (i, &v) in b[..r.frames].iter().enumerate() {
                                if v != pattern_expected(first + i as u64, c as u32) {
                                    corrupted += 1;
                                }
                            }
                        }
                        delivered += r.frames as u64;
                        lost += r.loss;
                        if r.frames == 0 {
                            std::thread::yield_now();
                        }
                    }
                    (delivered, lost, corrupted, nfr - 1)
                })
            })
            .collect();
        let mut chunk = vec![0i32; NFPC * CH];
        let mut l = 0;
        start.wait();
        for _ in 0..chunks {
            fill_pattern_interleaved(&mut chunk, CH as u32, l + 1);
            l = ring.publish(l, NFPC, CH, &Source::Interleaved(&chunk), || {});
            std::thread::yield_now();
        }
        readers.into_iter().map(|h| h.join().unwrap()).collect::<Vec<_>>()
    });
    for (k, (delivered, lost, corrupted, requested)) in results.into_iter().enumerate() {
        println!("FIGURE item 12: heap ring reader {k}: delivered={delivered} lost={lost} corrupted={corrupted} requested={requested} (miri: {})", cfg!(miri));
        assert_eq!(corrupted, 0, "reader {k} got torn samples");
        assert_eq!(requested, last);
        assert_eq!(delivered + lost, requested, "reader {k} accounting");
    }
}

/// The same on a real port file (mmap, futex): a writer thread and two reader threads (one
/// copying, one blocking in `wait`) in one process, for ThreadSanitizer builds of the whole
/// library (see docs/reliability.md); Miri cannot map files, so it skips this one.
#[test]
#[cfg_attr(miri, ignore = "Miri cannot mmap a file")]
fn mapped_port_threads_never_see_torn_frames_and_account_every_frame() {
    use bassport::{ChunkMeta, Geometry, Port, PortParams, Writer};
    let dir = bass_test_support::TempDir::shm("tsan-port");
    let path = dir.join("bass-tsan.port");
    let geometry = Geometry {
        channels: CH as u32,
        sample_rate: 48000,
        frames_per_chunk: NFPC as u32,
        chunks_on_port: NCOP as u32,
    };
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "tsan".into(), group: None }).unwrap();
    let chunks = 10_000u64;
    let last = chunks * NFPC as u64;
    let start = std::sync::Barrier::new(3);
    let results = std::thread::scope(|s| {
        let readers: Vec<_> = [false, true]
            .into_iter()
            .map(|blocking| {
                let (path, start) = (&path, &start);
                s.spawn(move || {
                    let port = Port::open_path(path).unwrap();
                    let n = 5usize;
                    let mut bufs = vec![vec![0i32; n]; CH];
                    let (mut nfr, mut delivered, mut lost, mut corrupted) = (1u64, 0u64, 0u64, 0u64);
                    start.wait();
                    while nfr <= last {
                        if blocking {
                            let _ = port.wait(nfr, std::time::Duration::from_secs(10));
                        }
                        let before = nfr;
                        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
                        let r = port.get_audio_data(n, &mut nfr, &mut outs).unwrap();
                        corrupted += bass_faults::count_corrupted(before + r.loss, r.frames, &bufs);
                        delivered += r.frames as u64;
                        lost += r.loss;
                    }
                    (delivered, lost, corrupted, nfr - 1)
                })
            })
            .collect();
        let mut chunk = vec![0i32; NFPC * CH];
        start.wait();
        for _ in 0..chunks {
            fill_pattern_interleaved(&mut chunk, CH as u32, w.last_frame_index() + 1);
            w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
            std::thread::yield_now();
        }
        readers.into_iter().map(|h| h.join().unwrap()).collect::<Vec<_>>()
    });
    for (k, (delivered, lost, corrupted, requested)) in results.into_iter().enumerate() {
        println!("FIGURE item 12: mapped port thread reader {k}: delivered={delivered} lost={lost} corrupted={corrupted} requested={requested}");
        assert_eq!(corrupted, 0, "reader {k} got torn samples");
        assert_eq!(requested, last);
        assert_eq!(delivered + lost, requested, "reader {k} accounting");
    }
}
