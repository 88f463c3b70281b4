//! Item 4 — torn-read stress. A writer process publishes the pattern signal (every sample
//! encodes its frame and channel) for `$BASS_FAULTS_TORN_SECS` seconds (default 60) into a
//! small window (8 chunks of 64 frames), one chunk every 50 µs, so the window wraps ~2400
//! times a second. Six reader processes of different speeds and kinds (busy copy, paced
//! copy, big slow blocks, blocking wait, zero-copy view, one repeatedly SIGSTOPped) check
//! every sample they are given.
//!
//! Pass: 0 corrupted samples in every reader; per reader delivered + lost = requested
//! exactly, and requested = every frame published; lastFrameIndex never goes backwards.

use std::time::{Duration, Instant};

use bass_faults::{env_secs, figure, Agent};
use bass_test_support::TempDir;

/// (mode, N, pause µs) of each reader; the last one is SIGSTOPped and SIGCONTed.
const READERS: [(&str, usize, u64); 6] = [
    ("copy", 64, 0),
    ("copy", 300, 20),
    ("copy", 2000, 500),
    ("wait", 256, 0),
    ("view", 512, 0),
    ("copy", 128, 0),
];

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn readers_of_any_speed_get_no_torn_sample_and_account_every_frame_for_a_minute() {
    let secs = env_secs("BASS_FAULTS_TORN_SECS", 60);
    let dir = TempDir::shm("torn");
    let port = dir.join("bass-torn.port");
    let p = port.to_str().unwrap();
    let mut writer = Agent::writer_held(p, 64, 8, &["--pace-us", "50", "--seconds", &secs.to_string()]);
    let mut readers: Vec<Agent> = READERS
        .iter()
        .map(|(mode, n, pause)| {
            Agent::spawn(&[
                "reader",
                "--port",
                p,
                "--mode",
                mode,
                "--n",
                &n.to_string(),
                "--pause-us",
                &pause.to_string(),
            ])
        })
        .collect();
    for r in &mut readers {
        r.expect_line("ready");
    }
    writer.send("go");
    let started = Instant::now();
    let stopped = readers.last().unwrap().pid() as libc::pid_t;
    let mut stops = 0u64;
    while writer.child.try_wait().unwrap().is_none() {
        // SAFETY: signalling our own child.
        unsafe { libc::kill(stopped, libc::SIGSTOP) };
        std::thread::sleep(Duration::from_millis(15));
        // SAFETY: as above.
        unsafe { libc::kill(stopped, libc::SIGCONT) };
        std::thread::sleep(Duration::from_millis(5));
        stops += 1;
    }
    // SAFETY: as above: make sure it runs to drain.
    unsafe { libc::kill(stopped, libc::SIGCONT) };
    let w = writer.result();
    let published = w.u("last");
    let elapsed = started.elapsed();
    let (mut checked, mut total_lost) = (0u64, 0u64);
    for (k, r) in readers.into_iter().enumerate() {
        let f = r.result();
        let (delivered, lost, corrupted, requested) =
            (f.u("delivered"), f.u("lost"), f.u("corrupted"), f.u("requested"));
        figure!(
            4,
            "reader {k} {:?}: delivered={delivered} lost={lost} corrupted={corrupted} requested={requested} reads={} loss_events={} view_overwritten={}",
            READERS[k],
            f.u("reads"),
            f.u("loss_events"),
            f.u("view_overwritten")
        );
        assert_eq!(corrupted, 0, "reader {k} {:?} was given corrupted samples", READERS[k]);
        assert_eq!(requested, published, "reader {k} must cover every published frame");
        assert_eq!(delivered + lost, requested, "reader {k}: delivered + lost != requested");
        assert_eq!(f.u("lfi_regressions"), 0, "reader {k} saw lastFrameIndex go backwards");
        assert!(delivered > 0, "reader {k} delivered nothing");
        checked += delivered;
        total_lost += lost;
    }
    figure!(
        4,
        "{:.1} s, {published} frames published ({} chunks), {checked} frames x 2 channels checked ({} samples), {total_lost} frames lost in total, 0 corrupted; reader 5 stopped {stops} times; writer max lateness {} us",
        elapsed.as_secs_f64(),
        w.u("chunks"),
        checked * 2,
        w.u("max_late_us")
    );
    assert!(elapsed >= Duration::from_secs(secs), "the run must last at least {secs} s");
}
