//! Many readers waiting on one port: while more than `DIRECT_ALL_MAX` (8) readers are woken
//! per publish, the writer hands the wakes to the wake thread, and it wakes everyone itself
//! again when they are gone. Up to `HAND_ALL_MIN` (32) readers it first wakes
//! `SPLIT_DIRECT` (2) itself; with more its own thread wakes none (before 2026-12-07 it woke 2
//! per publish however many waited, which the 40-reader test counts).
//! Every reader still gets every frame with its exact samples and exact accounting; no reader
//! is left sleeping (the waits have a 20 s guard, far above the run's length).

use bass_test_support::client as common;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use basskit::testsignal::fill_pattern_interleaved;
use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};

const NFPC: u32 = 64;

#[test]
fn many_waiting_readers_get_every_frame_through_the_wake_thread_and_few_get_direct_wakes() {
    let by_writer = readers_through_the_wake_thread(12, 600, Duration::from_micros(500));
    // 12 readers: the first 2 of a handed-over publish are woken by the writer itself.
    assert_eq!(median(&by_writer), 2, "readers the writer woke itself per handed-over publish, 12 readers");
}

#[test]
fn with_more_than_32_waiting_readers_the_writer_wakes_none_itself() {
    // Paced slower so that the 40 are asleep again at most publishes (the wake thread's count
    // picks the mode; a publish that finds fewer may wake some directly: hence the median).
    let by_writer = readers_through_the_wake_thread(40, 200, Duration::from_millis(4));
    // The waker before 2026-12-07 woke 2 itself in every publish however many waited.
    assert_eq!(median(&by_writer), 0, "readers the writer woke itself per handed-over publish, 40 readers");
}

fn median(v: &[u64]) -> u64 {
    let mut v = v.to_vec();
    v.sort_unstable();
    v[v.len() / 2]
}

/// `n_readers` reader threads each read every frame of `chunks` chunks published `pace` apart,
/// checked sample by sample; returns, per publish made while the wakes were handed over, how
/// many readers the writer's own thread woke.
fn readers_through_the_wake_thread(n_readers: usize, chunks: u64, pace: Duration) -> Vec<u64> {
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: NFPC, chunks_on_port: 4096 };
    let params = PortParams { geometry, device: "waker-test".into(), group: None };
    let mut w = Writer::create_at(&common::temp_port_path("waker"), &params).unwrap();
    let path = w.path().to_owned();
    let last = chunks * u64::from(NFPC);
    let start = Arc::new(std::sync::Barrier::new(n_readers + 1));
    let readers: Vec<_> = (0..n_readers)
        .map(|_| {
            let (path, start) = (path.clone(), start.clone());
            std::thread::spawn(move || {
                let port = Port::open_path(&path).unwrap();
                start.wait();
                let (mut nfr, mut delivered, mut lost, mut wrong) = (1u64, 0u64, 0u64, 0u64);
                let mut bufs = vec![vec![0i32; NFPC as usize]; 2];
                while nfr <= last {
                    let chunk_end = nfr.div_ceil(u64::from(NFPC)) * u64::from(NFPC);
                    port.wait(chunk_end, Duration::from_secs(20))
                        .expect("a published chunk wakes its waiters");
                    let before = nfr;
                    let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
                    let r = port.get_audio_data(NFPC as usize, &mut nfr, &mut outs).unwrap();
                    wrong += common::count_not_pattern(before + r.loss, r.frames, &bufs);
                    delivered += r.frames as u64;
                    lost += r.loss;
                }
                (delivered, lost, wrong, nfr)
            })
        })
        .collect();
    start.wait();
    let mut chunk = vec![0i32; 2 * NFPC as usize];
    let saw_helper = Arc::new(AtomicBool::new(false));
    // Publishes made while the wakes were already handed over, and the readers the writer's
    // own thread woke during them: the capture thread pays one hand-over, never a reader wake.
    let mut by_writer = Vec::new();
    for k in 0..chunks {
        fill_pattern_interleaved(&mut chunk, 2, k * u64::from(NFPC) + 1);
        let (before, was_handed_over) = (w.readers_woken_by_writer(), w.wakes_through_helper());
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
        if was_handed_over && w.wakes_through_helper() {
            by_writer.push(w.readers_woken_by_writer() - before);
        }
        if w.wakes_through_helper() {
            saw_helper.store(true, Ordering::Relaxed);
        }
        // Paced so that the readers are asleep again when most chunks are published.
        std::thread::sleep(pace);
    }
    for r in readers {
        let (delivered, lost, wrong, nfr) = r.join().unwrap();
        assert_eq!(wrong, 0, "samples that do not belong to their frame");
        assert_eq!(delivered + lost, last, "accounting: delivered {delivered} + lost {lost}");
        assert_eq!(lost, 0, "a 4096-chunk window loses nothing in this run");
        assert_eq!(nfr, last + 1);
    }
    assert!(
        saw_helper.load(Ordering::Relaxed),
        "{n_readers} waiting readers never moved the wakes to the wake thread"
    );
    assert!(
        by_writer.len() >= 10,
        "the wakes were handed over for only {} of {chunks} publishes",
        by_writer.len()
    );
    // The readers are gone: the wake thread's next wake finds at most DIRECT_ALL_MAX waiting,
    // so the writer takes the wakes back within a few publishes.
    let mut back = false;
    for k in chunks..chunks + 200 {
        fill_pattern_interleaved(&mut chunk, 2, k * u64::from(NFPC) + 1);
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
        if !w.wakes_through_helper() {
            back = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    assert!(back, "with no reader left the writer never took the wakes back");
    w.remove().unwrap();
    by_writer
}
