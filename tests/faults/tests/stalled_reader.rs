//! Item 2 — a reader SIGSTOPped for longer than the window, then SIGCONTed.
//!
//! Pass (exact variant): with the writer idle after the stall, the reader's next read
//! reports as loss exactly the frames that left the window (`ofi − nfr`), delivers the
//! whole window starting at `ofi`, and every sample is the pattern of its frame (no stale
//! sample from the previous lap of the ring).
//!
//! Pass (live variant): a paced writer process keeps publishing while a blocking reader is
//! stopped five times for 3× the window: every stop shows up as a loss whose first
//! delivered frame lies within the window bounds seen around the read, 0 corrupted samples,
//! delivered + lost = requested exactly. The writer's published chunks (of 400 scheduled)
//! and lateness are reported: a stopped reader cannot delay it — readers never write the port.
//!
//! Pass (broker variant): the same with a real `bassd` capturing `sim:pattern`: the broker
//! shows 0 xruns and 0 gap frames after the stalls, and kept real-time pace.

use std::time::Duration;

use bass_faults::{figure, Agent, Fields};
use bass_test_support::{acquire_req, Bassd, TempDir};
use basskit::testsignal::fill_pattern_interleaved;
use bassport::{ChunkMeta, Geometry, PortParams, Source, Writer};

fn proc_state(pid: u32) -> char {
    bassport::sys::process_start(pid).map(|(_, s)| s).unwrap_or('?')
}

/// Ends a `--log-loss` reader (it must exit cleanly); its RESULT fields and LOSS lines, each
/// loss checked against the window around its read (`nfpc` frames per chunk, `nfop` on the
/// port): the frames lost are exactly those that left the window.
fn reader_losses(r: Agent, nfpc: u64, nfop: u64) -> (Fields, Vec<Fields>) {
    let (status, lines) = r.finish();
    assert!(status.success(), "reader failed: {lines:?}");
    let rf = Fields::parse(lines.iter().rev().find(|l| l.starts_with("RESULT")).expect("RESULT"));
    let losses: Vec<Fields> =
        lines.iter().filter(|l| l.starts_with("LOSS")).map(|l| Fields::parse(l)).collect();
    for l in &losses {
        let first = l.u("nfr_before") + l.u("loss");
        let lo = (l.u("lfi_before") + 1).saturating_sub(nfop);
        let hi = (l.u("lfi_after") + nfpc + 1).saturating_sub(nfop);
        assert!(
            lo <= first && first <= hi,
            "loss does not match the window around the read: {l:?} (bounds {lo}..={hi})"
        );
    }
    (rf, losses)
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn stopped_reader_reports_exactly_the_frames_that_left_the_window_and_no_stale_sample() {
    let dir = TempDir::shm("stall");
    let path = dir.join("bass-stall.port");
    let (nfpc, ncop) = (64u32, 8u32);
    let nfop = u64::from(nfpc * ncop);
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: nfpc, chunks_on_port: ncop };
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "stall".into(), group: None }).unwrap();
    let mut chunk = vec![0i32; (nfpc * 2) as usize];
    let mut publish = |w: &mut Writer, chunks: u32| {
        for _ in 0..chunks {
            fill_pattern_interleaved(&mut chunk, 2, w.last_frame_index() + 1);
            w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
        }
    };
    publish(&mut w, 4);
    let mut r = Agent::spawn(&["stepped", "--port", path.to_str().unwrap(), "--nfr", "1"]);
    r.expect_line("ready");
    r.send("read");
    let f = Fields::parse(&r.expect_line("READ"));
    assert_eq!((f.u("n"), f.u("loss"), f.u("nfr"), f.u("corrupted")), (256, 0, 257, 0), "{f:?}");
    for (round, stall_chunks) in [(1u32, 20u32), (2, 9), (3, 8), (4, 200)].into_iter() {
        r.signal(libc::SIGSTOP);
        assert!(
            bass_test_support::wait_until(Duration::from_secs(5), || proc_state(r.pid()) == 'T'),
            "reader not stopped"
        );
        let nfr_before = w.last_frame_index() + 1;
        publish(&mut w, stall_chunks);
        let lfi = w.last_frame_index();
        r.signal(libc::SIGCONT);
        r.send("read");
        let f = Fields::parse(&r.expect_line("READ"));
        let ofi = (lfi + 1).saturating_sub(nfop);
        let expect_loss = ofi.saturating_sub(nfr_before);
        figure!(
            2,
            "exact round {round}: stalled over {} frames (window {nfop}): loss={} (expected {expect_loss}) n={} first={} corrupted={} stale={}",
            u64::from(stall_chunks * nfpc),
            f.u("loss"),
            f.u("n"),
            f.u("first"),
            f.u("corrupted"),
            f.u("stale")
        );
        assert_eq!(f.u("nfr_before"), nfr_before);
        assert_eq!(f.u("loss"), expect_loss, "loss must be exactly the frames that left the window: {f:?}");
        assert_eq!(f.u("first"), nfr_before + expect_loss);
        assert_eq!(f.u("n"), lfi - f.u("first") + 1, "the rest of the window is delivered: {f:?}");
        assert_eq!(f.u("nfr"), lfi + 1);
        assert_eq!(f.u("corrupted"), 0, "stale or torn samples delivered: {f:?}");
    }
    r.send("quit");
    assert!(r.finish().0.success());
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn live_writer_is_not_delayed_by_a_stopped_reader_whose_losses_are_exact() {
    let dir = TempDir::shm("stall-live");
    let path = dir.join("bass-stall-live.port");
    let p = path.to_str().unwrap();
    // 48 kHz in real time: 10 ms chunks, a 100 ms window.
    let (nfpc, ncop, pace_us) = (480u64, 10u64, 10_000u64);
    let nfop = nfpc * ncop;
    let mut w = Agent::writer_held(p, 480, 10, &["--pace-us", "10000", "--seconds", "4"]);
    let mut r = Agent::spawn(&["reader", "--port", p, "--mode", "wait", "--n", "480", "--log-loss"]);
    r.expect_line("ready");
    w.send("go");
    let stall = Duration::from_millis(300);
    let stops = 5;
    std::thread::sleep(Duration::from_millis(300));
    for _ in 0..stops {
        r.signal(libc::SIGSTOP);
        std::thread::sleep(stall);
        r.signal(libc::SIGCONT);
        std::thread::sleep(Duration::from_millis(250));
    }
    let wf = w.result();
    let (rf, losses) = reader_losses(r, nfpc, nfop);
    let published = wf.u("last");
    figure!(
        2,
        "live: reader stopped {stops}x {} ms (window {} ms): {} loss events, lost={} delivered={} corrupted={}; writer published {} chunks ({} scheduled), max lateness {} us, max publish {} us",
        stall.as_millis(),
        nfop * 1000 / 48000,
        losses.len(),
        rf.u("lost"),
        rf.u("delivered"),
        rf.u("corrupted"),
        wf.u("chunks"),
        4_000_000 / pace_us,
        wf.u("max_late_us"),
        wf.u("max_publish_us")
    );
    assert_eq!(rf.u("corrupted"), 0);
    assert_eq!(rf.u("requested"), published);
    assert_eq!(rf.u("delivered") + rf.u("lost"), published);
    assert!(losses.len() >= stops, "every stop longer than the window must show up as a loss");
    // The writer's schedule (4 s of 10 ms chunks) is reported above, not asserted: on a
    // loaded machine a starved writer publishes late, which is timing, not correctness.
    assert!(wf.u("chunks") > 0);
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn broker_shows_no_xrun_while_a_reader_is_stopped_longer_than_the_window() {
    let dir = TempDir::shm("stall-bassd");
    let b = Bassd::start_stock(dir.path(), "st", &[], &[]);
    let mut c = b.client();
    // 48 kHz, 10 ms chunks, a 100 ms window.
    c.acquire(&acquire_req("sim:pattern", 48000, 480, 10, 2)).unwrap();
    let (nfpc, nfop) = (480u64, 4800u64);
    let mut r = Agent::spawn(&[
        "reader",
        "--port",
        b.port_path().to_str().unwrap(),
        "--mode",
        "wait",
        "--n",
        "480",
        "--log-loss",
    ]);
    r.expect_line("ready");
    let t0 = std::time::Instant::now();
    let lfi0 = c.status().unwrap().last_frame_index;
    let stops = 5;
    for _ in 0..stops {
        std::thread::sleep(Duration::from_millis(200));
        r.signal(libc::SIGSTOP);
        std::thread::sleep(Duration::from_millis(300));
        r.signal(libc::SIGCONT);
    }
    std::thread::sleep(Duration::from_millis(200));
    let s = c.status().unwrap();
    let elapsed = t0.elapsed().as_secs_f64();
    c.stop().unwrap();
    let (rf, losses) = reader_losses(r, nfpc, nfop);
    let rate = (s.last_frame_index - lfi0) as f64 / elapsed;
    figure!(
        2,
        "bassd sim:pattern 48 kHz, window 100 ms: reader stopped {stops}x 300 ms: {} loss events, lost={} delivered={} corrupted={}; broker xruns={} gap_frames={} and published {rate:.0} frames/s meanwhile",
        losses.len(),
        rf.u("lost"),
        rf.u("delivered"),
        rf.u("corrupted"),
        s.xruns,
        s.gap_frames
    );
    assert_eq!((s.xruns, s.gap_frames), (0, 0), "a stopped reader caused xruns or gaps");
    assert_eq!(rf.u("corrupted"), 0);
    assert_eq!(rf.u("delivered") + rf.u("lost"), rf.u("requested"));
    assert!(losses.len() >= stops);
}
