//! Item 1 — the broker SIGKILLed at random points.
//!
//! Part A: 100 runs of a real `bassd` capturing `sim:pattern` (48 kHz, 10 ms chunks),
//! killed after a random 0–80 ms (during start-up, between chunks, or while publishing).
//! Part B: 100 runs of an unpaced pattern writer with large chunks (the same port writer
//! the broker uses), killed at a random point: almost always in the middle of a chunk
//! (write intent ahead of lastFrameIndex at death), which a paced broker rarely is.
//!
//! In every run two readers are attached: one blocked in `wait` for a far-future frame,
//! one following the stream (wait for the next chunk, read it, check every sample).
//! Pass: both readers return `WriterGone` (never a timeout: they wait with 20 s) — the
//! delay from the kill to that result is reported (median, max); the follower never got a
//! frame beyond the last published lastFrameIndex, and no corrupted sample; a post-mortem
//! read of the whole window delivers only intact pattern frames (the frames the dying
//! writer may have been overwriting are reported as loss).

use std::os::unix::process::ExitStatusExt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use bass_faults::{count_corrupted, figure, median_max, Agent, Rng};
use bass_test_support::{acquire_req, Bassd, TempDir};
use bassport::{Error, Port};

const PATIENCE: Duration = Duration::from_secs(20);

struct Outcome {
    waiter_delay: Duration,
    follower_delay: Duration,
    mid_chunk: bool,
    delivered: u64,
}

/// Attaches the two readers to `path`, calls `kill` after `delay`, and checks the outcome.
fn run(path: &std::path::Path, delay: Duration, kill: impl FnOnce()) -> Outcome {
    let port = Arc::new(Port::open_path(path).expect("open port"));
    let started = Arc::new(AtomicBool::new(false));
    let waiter = {
        let port = port.clone();
        std::thread::spawn(move || {
            let r = port.wait(u64::MAX >> 8, PATIENCE);
            (r, Instant::now())
        })
    };
    let follower = {
        let (port, started) = (port.clone(), started.clone());
        std::thread::spawn(move || {
            let n = 4096usize;
            let channels = port.geometry().channels as usize;
            let mut bufs = vec![vec![0i32; n.min(port.frames_on_port() as usize)]; channels];
            let (mut nfr, mut max_frame, mut corrupted, mut delivered) = (1u64, 0u64, 0u64, 0u64);
            started.store(true, Ordering::Relaxed);
            let gone = loop {
                match port.wait(nfr, PATIENCE) {
                    Ok(_) => {}
                    Err(e) => break (e, Instant::now()),
                }
                let before = nfr;
                let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
                let r = port.get_audio_data(n, &mut nfr, &mut outs).expect("read");
                corrupted += count_corrupted(before + r.loss, r.frames, &bufs);
                delivered += r.frames as u64;
                if r.frames > 0 {
                    max_frame = max_frame.max(nfr - 1);
                }
            };
            (gone, max_frame, corrupted, delivered)
        })
    };
    while !started.load(Ordering::Relaxed) {
        std::thread::yield_now();
    }
    std::thread::sleep(delay);
    let t_kill = Instant::now();
    kill();
    let (wres, wt) = waiter.join().unwrap();
    let ((fres, ft), max_frame, corrupted, delivered) = follower.join().unwrap();
    assert!(matches!(wres, Err(Error::WriterGone { .. })), "waiter: expected WriterGone, got {wres:?}");
    assert!(matches!(fres, Error::WriterGone { .. }), "follower: expected WriterGone, got {fres:?}");
    assert_eq!(corrupted, 0, "the follower got corrupted samples");
    let info = port.info().unwrap();
    let (lfi, nfop) = (info.last_frame_index, port.frames_on_port());
    assert!(!info.writer_alive);
    assert!(max_frame <= lfi, "the follower got frame {max_frame} beyond the last published {lfi}");
    // Post-mortem: read the whole window.
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; nfop as usize]; channels];
    let mut nfr = 0u64;
    let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
    let r = port.get_audio_data(nfop as usize, &mut nfr, &mut outs).unwrap();
    let first = r.loss;
    assert_eq!(count_corrupted(first, r.frames, &bufs), 0, "post-mortem read delivered torn or wrong frames");
    assert!(nfr <= lfi + 1);
    let intent = intent_of(path);
    let mid_chunk = intent > lfi;
    if mid_chunk && r.frames > 0 {
        assert!(
            first + nfop > intent,
            "frame {first} shares its slot with a frame being written (intent {intent})"
        );
    }
    Outcome { waiter_delay: wt - t_kill, follower_delay: ft - t_kill, mid_chunk, delivered }
}

/// The header's write intent (offset 136), read from the file.
fn intent_of(path: &std::path::Path) -> u64 {
    use std::os::unix::fs::FileExt;
    let f = std::fs::File::open(path).unwrap();
    let mut b = [0u8; 8];
    f.read_exact_at(&mut b, 136).unwrap();
    u64::from_ne_bytes(b)
}

fn report(part: &str, outcomes: &[Outcome], seed: u64) {
    let w: Vec<Duration> = outcomes.iter().map(|o| o.waiter_delay).collect();
    let f: Vec<Duration> = outcomes.iter().map(|o| o.follower_delay).collect();
    let (wm, wx) = median_max(&w);
    let (fm, fx) = median_max(&f);
    figure!(
        1,
        "{part}: {} kills (seed {seed}), {} mid-chunk; detection delay (kill -> WriterGone) blocked waiter median {:.1} ms max {:.1} ms, following reader median {:.1} ms max {:.1} ms (timeout 20 s); {} frames delivered, 0 corrupted, none beyond lastFrameIndex",
        outcomes.len(),
        outcomes.iter().filter(|o| o.mid_chunk).count(),
        wm.as_secs_f64() * 1e3,
        wx.as_secs_f64() * 1e3,
        fm.as_secs_f64() * 1e3,
        fx.as_secs_f64() * 1e3,
        outcomes.iter().map(|o| o.delivered).sum::<u64>()
    );
}

fn runs() -> usize {
    std::env::var("BASS_FAULTS_KILLS").ok().and_then(|s| s.parse().ok()).unwrap_or(100)
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn killed_broker_ends_every_wait_with_writer_gone_and_delivers_nothing_unpublished() {
    let seed = bass_faults::seed();
    let mut rng = Rng::with_seed(seed);
    let mut outcomes = Vec::new();
    for _ in 0..runs() {
        let dir = TempDir::shm("bkill");
        let mut b = Bassd::start_stock(dir.path(), "k", &[], &[]);
        b.client().acquire(&acquire_req("sim:pattern", 48000, 480, 20, 2)).expect("acquire");
        let delay = Duration::from_micros(rng.u64(..80_000));
        let path = b.port_path();
        outcomes.push(run(&path, delay, || b.kill(libc::SIGKILL)));
    }
    report("bassd (sim:pattern, 48 kHz, 10 ms chunks)", &outcomes, seed);
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn writer_killed_mid_chunk_leaves_only_intact_frames_readable() {
    let seed = bass_faults::seed();
    let mut rng = Rng::with_seed(seed);
    let mut outcomes = Vec::new();
    for _ in 0..runs() {
        let dir = TempDir::shm("wkill");
        let path = dir.join("bass-wkill.port");
        let mut w =
            Agent::spawn(&["writer", "--port", path.to_str().unwrap(), "--nfpc", "65536", "--ncop", "4"]);
        w.expect_line("ready");
        let delay = Duration::from_micros(rng.u64(..30_000));
        outcomes.push(run(&path, delay, || {
            w.signal(libc::SIGKILL);
            let st = w.child.wait().expect("wait for the writer");
            assert_eq!(st.signal(), Some(libc::SIGKILL), "the writer ended with {st} before its kill");
        }));
    }
    report("unpaced writer (64 Ki-frame chunks)", &outcomes, seed);
    let mid = outcomes.iter().filter(|o| o.mid_chunk).count();
    assert!(mid > 0, "no kill landed mid-chunk");
}
