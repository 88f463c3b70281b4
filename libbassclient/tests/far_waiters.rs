//! A reader waiting for a frame far ahead (a 1 s block at 32-frame chunks: 1500 chunks)
//! sleeps on the futex bit no chunk uses until its chunk is near by the port's rate, instead
//! of on its chunk's bit, which every 31st chunk's publish wakes (48 times a second at 1500
//! chunks/s). What is left are the liveness slices (one per 100 ms) and the last stretch.
//! Counted from the kernel's own tally of the waiting thread's sleeps (voluntary context
//! switches in /proc), with every frame of the block read back and checked.

use bass_test_support::client as common;

use std::time::{Duration, Instant};

use basskit::testsignal::fill_pattern_interleaved;
use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};

const NFPC: u32 = 32;
const RATE: u32 = 48_000;

/// How often the calling thread has gone to sleep (its voluntary context switches).
fn sleeps_of_this_thread() -> u64 {
    let status = std::fs::read_to_string("/proc/thread-self/status").unwrap();
    let line = status.lines().find(|l| l.starts_with("voluntary_ctxt_switches:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

#[test]
fn a_reader_waiting_a_second_ahead_sleeps_about_once_per_liveness_slice() {
    let geometry = Geometry { channels: 2, sample_rate: RATE, frames_per_chunk: NFPC, chunks_on_port: 4096 };
    let params = PortParams { geometry, device: "far-waiter-test".into(), group: None };
    let mut w = Writer::create_at(&common::temp_port_path("far"), &params).unwrap();
    let path = w.path().to_owned();
    let mut chunk = vec![0i32; 2 * NFPC as usize];
    let mut k = 0u64;
    let mut publish = |w: &mut Writer| {
        fill_pattern_interleaved(&mut chunk, 2, k * u64::from(NFPC) + 1);
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
        k += 1;
    };
    publish(&mut w);
    let block = RATE as usize; // 1 s
    let reader = std::thread::spawn(move || {
        let port = Port::open_path(&path).unwrap();
        let mut results = Vec::new();
        for _ in 0..2 {
            let mut nfr = port.wait(1, Duration::from_secs(10)).unwrap() + 1;
            let frame = nfr + block as u64 - 1;
            let before = sleeps_of_this_thread();
            let lfi = port.wait(frame, Duration::from_secs(10)).unwrap();
            let sleeps = sleeps_of_this_thread() - before;
            let first = nfr;
            let mut bufs = vec![vec![0i32; block]; 2];
            let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
            let r = port.get_audio_data(block, &mut nfr, &mut outs).unwrap();
            let wrong = common::count_not_pattern(first + r.loss, r.frames, &bufs);
            results.push((frame, lfi, sleeps, r.frames, r.loss, wrong));
        }
        results
    });
    // The writer at the port's rate (deadlines: a late sleep catches up), for 2.3 s.
    let (t0, period) =
        (Instant::now(), Duration::from_nanos(u64::from(NFPC) * 1_000_000_000 / u64::from(RATE)));
    for n in 1..=3450u32 {
        std::thread::sleep((t0 + period * n).saturating_duration_since(Instant::now()));
        publish(&mut w);
    }
    let results = reader.join().unwrap();
    for (frame, lfi, sleeps, frames, loss, wrong) in results {
        assert!(lfi >= frame, "returned {lfi} before frame {frame} was published");
        assert_eq!((frames, loss, wrong), (block, 0, 0), "the 1 s block ending at frame {frame}");
        // 10 liveness slices, the sleep on the chunk's own bit, a wake or two to spare. On the
        // chunk's bit all along (before 2026-12-07) it slept 49 times or more.
        assert!(sleeps <= 20, "the wait for frame {frame}, 1500 chunks ahead, slept {sleeps} times");
    }
    w.remove().unwrap();
}
