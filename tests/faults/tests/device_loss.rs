//! Item 10 — device loss and recovery with jackd (dummy backend) behind ALSA's jack PCM.
//!
//! `bassd` captures `bass_jack` (ALSA's jack plugin over `jackd -d dummy`, 48 kHz, paced in
//! real time); a reader process follows the port by name across acquisitions. Three times:
//! jackd is killed (SIGKILL, SIGTERM, SIGKILL) during capture; then restarted, and an
//! Acquire issued.
//!
//! Pass: each loss becomes an error state visible to readers (the follower's wait returns
//! a device error with code DEVICE_STALLED or DEVICE_LOST; status shows state Error) — the
//! delay from the kill to the reader seeing it is reported; after the restart and Acquire,
//! capture resumes with epoch + 1 and the same reader continues in the new epoch; every
//! sample it reads is the dummy backend's silence. Skipped (reported) if jackd or the ALSA
//! jack plugin is missing; with `BASS_TESTS_NO_SKIP=1` (CI) that is a failure.

use std::time::{Duration, Instant};

use bass_faults::{figure, median_max, Agent, Fields};
use bass_test_support::{acquire_req, eventually, jack_missing, skip, Bassd, JackRig, Jackd, TempDir};
use bassport::format::error_code;

/// Waits until the broker captures in `epoch` and has published frame `frames`.
fn capturing(c: &mut bassport::control::Client, epoch: u64, frames: u64) {
    eventually(&format!("capture in epoch {epoch} up to frame {frames}"), || {
        let s = c.status().expect("status");
        (s.epoch == epoch && s.state() == Some(bassport::State::Capturing) && s.last_frame_index >= frames)
            .then_some(())
    });
}

fn mono_ns() -> u64 {
    bassport::sys::monotonic_ns()
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn killed_jackd_is_an_error_readers_see_and_a_new_acquire_resumes_in_a_new_epoch() {
    if skip(jack_missing()) {
        figure!(10, "SKIPPED: jackd or ALSA's jack plugin is missing");
        return;
    }
    // A fixed server name: JACK keeps 8 server slots per machine and frees a SIGKILLed
    // server's slot only when a server of the same name starts again, so a per-run name
    // would use up the slots after a few runs.
    let rig = JackRig::new(TempDir::shm("jack"), "bass-faults-t10");
    let logs = TempDir::shm("jack-logs");
    let mut jackd = Jackd::start(&rig.jack_name, 48000, logs.path());
    let b = Bassd::start_stock(rig.path(), "jk", &["--allow-device", "bass_jack"], &rig.env());
    let mut c = b.client();
    let mut epoch = c.acquire(&acquire_req("bass_jack", 48000, 480, 200, 2)).expect("acquire on jack").epoch;
    let mut follower = Agent::spawn(&[
        "follow",
        "--port",
        b.port_path().to_str().unwrap(),
        "--n",
        "480",
        "--expect",
        "zero",
    ]);
    follower.expect_line("ready");
    follower.expect_line("EPOCH");
    let mut delays = Vec::new();
    let mut codes = Vec::new();
    for sig in [libc::SIGKILL, libc::SIGTERM, libc::SIGKILL] {
        // Capture runs (half a second of frames in this epoch), then pull the plug.
        capturing(&mut c, epoch, 24000);
        let kill_ns = mono_ns();
        jackd.kill(sig);
        let dev = Fields::parse(&follower.expect_line("DEVICE"));
        let code = dev.u("code") as u32;
        assert!(
            code == error_code::DEVICE_STALLED || code == error_code::DEVICE_LOST,
            "device error code {code}"
        );
        delays.push(Duration::from_nanos(dev.u("at_ns").saturating_sub(kill_ns)));
        codes.push(code);
        let s = c.status().unwrap();
        assert_eq!(s.state(), Some(bassport::State::Error), "status after the loss");
        assert_eq!(s.epoch, epoch);
        // Recovery: a new server and a new Acquire.
        jackd = Jackd::start(&rig.jack_name, 48000, logs.path());
        let end = Instant::now() + Duration::from_secs(20);
        let a = loop {
            match c.acquire(&acquire_req("bass_jack", 48000, 480, 200, 2)) {
                Ok(a) => break a,
                Err(e) if Instant::now() < end => {
                    eprintln!("acquire after restart: {e}");
                    std::thread::sleep(Duration::from_millis(200));
                }
                Err(e) => panic!("no Acquire after the jackd restart: {e}"),
            }
        };
        assert!(a.epoch > epoch, "a new acquisition must have a new epoch");
        epoch = a.epoch;
        let e = follower.expect_line("EPOCH");
        assert_eq!(
            e.split_whitespace().nth(1).and_then(|v| v.parse::<u64>().ok()),
            Some(epoch),
            "reader follows to the new epoch: {e}"
        );
    }
    // Capture resumed in the last epoch.
    capturing(&mut c, epoch, 24000);
    follower.close_stdin();
    let rf = follower.result();
    let (med, max) = median_max(&delays);
    figure!(
        10,
        "3 jackd kills (SIGKILL, SIGTERM, SIGKILL) during capture: error codes {codes:?} (1 lost, 2 stalled) seen by a waiting reader after median {:.0} ms, max {:.0} ms; after jackd restart + Acquire capture resumed each time with a new epoch (final epoch {epoch}); the reader followed {} epochs, delivered {} frames, lost {}, {} non-silent samples",
        med.as_secs_f64() * 1e3,
        max.as_secs_f64() * 1e3,
        rf.u("epochs"),
        rf.u("delivered"),
        rf.u("lost"),
        rf.u("corrupted")
    );
    assert_eq!(rf.u("corrupted"), 0, "the dummy backend captures silence");
    assert_eq!(rf.u("epochs"), 4);
    assert_eq!(rf.u("device_errors"), 3);
    assert!(rf.u("delivered") > 0);
}
