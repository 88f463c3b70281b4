//! Real ALSA paced in real time without a sound card: ALSA's `jack` PCM plugin over a
//! `jackd -d dummy` server that each test starts (its own server name). Killing jackd is an
//! unplug that ALSA never reports — the jack plugin just stops delivering — so the stall
//! watchdog must catch it.

use std::time::{Duration, Instant};

use bass_test_support::*;
use bassport::format::{error_code, State};
use bassport::{Error, Port};

const RATE: u32 = 48000;

/// A jack rig with a fixed server name per test: JACK keeps 8 server slots per machine, and
/// the slot of a server killed with SIGKILL is only reclaimed when a server of the same name
/// starts.
fn rig(tag: &str) -> JackRig {
    JackRig::new(TempDir::new(tag), &format!("bass-test-{tag}"))
}

/// A broker capturing the rig's own PCM (not a card reference, so the operator allows it).
fn bassd(rig: &JackRig) -> Bassd {
    Bassd::start(rig.path(), "default", &["--allow-device", "bass_jack"], &rig.env())
}

#[test]
fn jack_capture_is_paced_and_a_killed_server_is_a_lost_device_until_the_next_acquire() {
    let rig = rig("jack");
    let mut jackd = rig.jackd(RATE);
    let b = bassd(&rig);
    let mut c = b.client();
    let a = c.acquire(&acquire_req("bass_jack", RATE, 480, 200, 2)).unwrap();
    assert_eq!(a.format, "FLOAT_LE", "the jack plugin offers FLOAT only");
    let mut epoch = a.epoch;
    let port = b.port();
    wait_frame(&port, 48_000);
    // Paced: one second of frames spans about one second of timestamps (the unpaced file
    // plugin would deliver them in milliseconds). Loose bounds: this checks pacing, not timing.
    let (t0, t1) = (port.chunk_info(1).unwrap(), port.chunk_info(47_521).unwrap());
    let span = (t1.mono_ns - t0.mono_ns) as f64 / 1e9;
    // (Bounds wide enough for a loaded machine: the unpaced alternative is ~1000x off.)
    let info = port.info().unwrap();
    assert!(
        (0.5..1.5).contains(&span),
        "47520 frames at 48 kHz spanned {span} s of timestamps (xruns {}, gap frames {})",
        info.xruns,
        info.gap_frames
    );
    for c in read_frames(&port, 1, 48_000) {
        assert!(c.iter().all(|&s| s == 0), "the dummy backend captures silence");
    }

    let mut port = port;
    for sig in [libc::SIGKILL, libc::SIGTERM] {
        // A reader waiting for far-future frames is woken with the device error.
        let waiter = std::thread::spawn({
            let path = b.port_path();
            move || Port::open_path(&path).unwrap().wait(u64::MAX >> 8, PATIENCE)
        });
        // Let the waiter block first (it also works if it opens after the loss).
        std::thread::sleep(Duration::from_millis(50));
        jackd.kill(sig);
        match waiter.join().unwrap() {
            Err(Error::Device { code, message }) => {
                assert!(code == error_code::DEVICE_STALLED || code == error_code::DEVICE_LOST, "code {code}");
                assert!(message.contains("device stalled") || message.contains("lost"), "{message}");
            }
            other => panic!("signal {sig}: expected a device error, got {other:?}"),
        }
        let s = c.status().unwrap();
        assert_eq!(s.state, State::Error as u32);
        assert_eq!(s.epoch, epoch);

        // A new server and a new Acquire: capture resumes with a new epoch.
        jackd = rig.jackd(RATE);
        let a = eventually("an Acquire on the restarted jackd", || {
            c.acquire(&acquire_req("bass_jack", RATE, 480, 200, 2)).ok()
        });
        assert_eq!(a.epoch, epoch + 1);
        epoch = a.epoch;
        assert!(matches!(port.wait(u64::MAX >> 8, PATIENCE), Err(Error::Restarted)));
        port = b.port();
        wait_frame(&port, 4800);
        assert_eq!(c.status().unwrap().state, State::Capturing as u32);
    }
}

#[test]
fn jack_refuses_what_the_device_cannot_do_with_clear_messages() {
    let rig = rig("jackbad");
    let _jackd = rig.jackd(RATE);
    let b = bassd(&rig);
    let mut c = b.client();
    let mut s16 = acquire_req("bass_jack", RATE, 480, 20, 2);
    s16.format = Some("S16_LE".into());
    let cases = [
        (
            acquire_req("bass_jack", 44100, 441, 20, 2),
            "sample rate 44100 Hz is not supported by device \"bass_jack\" (it supports only 48000 Hz)",
        ),
        (
            acquire_req("bass_jack", RATE, 480, 20, 3),
            "3 channels are not supported by device \"bass_jack\" (it supports only 2)",
        ),
        (s16, "sample format S16_LE is not supported by device \"bass_jack\""),
    ];
    for (r, want) in cases {
        match c.acquire(&r) {
            Err(Error::Broker(m)) => assert!(m.contains(want), "{m:?} does not say {want:?}"),
            other => panic!("{r:?} was not refused: {other:?}"),
        }
        // Refused before anything was touched: no port was created.
        assert!(!b.port_path().exists(), "a refused Acquire created a port");
        assert_eq!(c.status().unwrap().state, State::Idle as u32);
    }
    // And the broker is still fine.
    c.acquire(&acquire_req("bass_jack", RATE, 480, 20, 2)).unwrap();
    wait_frame(&b.port(), 960);
}

/// Freezing the broker (SIGSTOP) overruns the device buffer: the overrun is recovered, counted
/// and zero-filled, and the acquisition goes on.
#[test]
fn an_overrun_is_recovered_counted_and_zero_filled() {
    let rig = rig("jackxrun");
    let _jackd = rig.jackd(RATE);
    let b = bassd(&rig);
    let mut c = b.client();
    c.acquire(&acquire_req("bass_jack", RATE, 480, 400, 2)).unwrap();
    let port = b.port();
    wait_frame(&port, 4800);
    b.signal(libc::SIGSTOP);
    let frozen = Instant::now();
    while frozen.elapsed() < Duration::from_millis(1000) {
        std::thread::sleep(Duration::from_millis(50));
    }
    b.signal(libc::SIGCONT);
    let info = eventually("the overrun to be counted", || {
        let i = port.info().unwrap();
        (i.xruns > 0 && i.gap_frames > 0).then_some(i)
    });
    assert_eq!(info.state, Some(State::Capturing));
    // Capture goes on after the gap.
    wait_frame(&port, info.last_frame_index + 4800);
    assert_eq!(c.status().unwrap().state, State::Capturing as u32);
}

/// A real overrun reported by ALSA (EPIPE): the capture thread is held inside a read (the
/// `file` plugin's infile is an empty FIFO) while the `jack` plugin below keeps filling the
/// buffer. When the FIFO gets data, the read completes, the next one fails with EPIPE, and the
/// broker restarts the stream, counts the overrun and zero-fills the time it lost; the data
/// after the gap continue exactly where they stopped.
#[test]
fn an_alsa_reported_overrun_is_recovered_and_the_data_resume_exactly() {
    let rig = rig("jackepipe");
    let fifo = rig.path().join("in.fifo");
    {
        use std::os::unix::ffi::OsStrExt;
        let c = std::ffi::CString::new(fifo.as_os_str().as_bytes()).unwrap();
        // SAFETY: valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    }
    let rc = format!(
        "pcm.bass_jack {{\n  type jack\n  capture_ports {{ 0 system:capture_1 1 system:capture_2 }}\n}}\n\
         pcm.bass_held {{\n  type file\n  slave.pcm \"bass_jack\"\n  file \"/dev/null\"\n  infile \"{}\"\n  format \"raw\"\n}}\n",
        fifo.display()
    );
    std::fs::write(rig.path().join("asoundrc"), rc).unwrap();
    let _jackd = rig.jackd(RATE);
    let mut w = std::fs::OpenOptions::new().read(true).write(true).open(&fifo).unwrap();
    let b = Bassd::start(
        rig.path(),
        "default",
        &["--stall-ms", "10000", "--allow-device", "bass_*"],
        &[
            ("ALSA_CONFIG_PATH", &rig.alsa_path),
            ("JACK_DEFAULT_SERVER", &rig.jack_name),
            ("JACK_NO_START_SERVER", "1"),
            ("JACK_NO_AUDIO_RESERVATION", "1"),
        ],
    );
    let a = b.client().acquire(&acquire_req("bass_held", RATE, 480, 400, 2)).unwrap();
    assert_eq!(a.format, "FLOAT_LE");
    // The broker is now blocked on the empty FIFO; let the jack plugin overrun its buffer.
    std::thread::sleep(Duration::from_millis(1000));
    use std::io::Write;
    let frames = 48_000usize;
    let value = |k: usize, c: usize| ((k % 30_000) as f32 + 1.0) / 32768.0 * if c == 0 { 1.0 } else { -1.0 };
    let mut raw = Vec::with_capacity(frames * 8);
    for k in 0..frames {
        for c in 0..2 {
            raw.extend_from_slice(&value(k, c).to_le_bytes());
        }
    }
    // SAFETY: fcntl on an open pipe.
    unsafe { libc::fcntl(std::os::fd::AsRawFd::as_raw_fd(&w), libc::F_SETPIPE_SZ, 1 << 20) };
    w.write_all(&raw).unwrap();
    let port = b.port();
    let info = eventually("the overrun to be counted", || {
        let i = port.info().unwrap();
        (i.xruns > 0 && i.gap_frames > 0 && i.last_frame_index > i.gap_frames + 4800).then_some(i)
    });
    let expect = |k: usize, c: usize| convert_float(value(k, c));
    // Frames 1..=n0 are data 0..n0, then gap_frames zeros, then data n0.. again.
    let total = (info.last_frame_index).min(40_000);
    let d = read_frames(&port, 1, total);
    let n0 = (0..total as usize).find(|&i| d[0][i] == 0).expect("a zero-filled gap");
    assert!(n0 > 0, "data before the gap");
    let frame = |i: usize| (d[0][i], d[1][i]);
    let before_ok = (0..n0).all(|i| frame(i) == (expect(i, 0), expect(i, 1)));
    assert!(before_ok, "the {n0} frames before the gap are the first {n0} of the FIFO");
    let gap = (n0..total as usize).take_while(|&i| frame(i) == (0, 0)).count();
    assert!(gap as u64 <= info.gap_frames, "gap {gap}, header {}", info.gap_frames);
    let bad = (n0 + gap..total as usize).find(|&i| frame(i) != (expect(i - gap, 0), expect(i - gap, 1)));
    assert_eq!(bad, None, "after the gap of {gap} frames the FIFO data continue exactly");
    assert_eq!(b.client().status().unwrap().state, State::Capturing as u32);
    // It went through ALSA's overrun (EPIPE + prepare/start), not the timestamp heuristics.
    let log = b.log_text();
    assert!(log.contains("overrun (") && log.contains("restarting the stream"), "{log}");
    drop(w);
}

fn convert_float(x: f32) -> i32 {
    (f64::from(x) * 2_147_483_648.0).round() as i32
}

/// Issue 33 item 3: a configured acquisition (`--acquire`) whose device is not there yet —
/// ALSA's jack PCM before its jackd starts, as a USB array that enumerates after bassd — is
/// tried again with a backoff, Status says what the broker waits for (not "no acquisition"),
/// and capture starts by itself once the device is there (before: idle until someone came).
#[test]
fn a_configured_device_that_appears_late_is_picked_up_by_itself() {
    let rig = rig("late");
    let args = [
        "--allow-device",
        "bass_jack",
        "--acquire",
        "bass_jack",
        "--rate",
        "48000",
        "--frames",
        "480",
        "--chunks",
        "200",
        "--channels",
        "2",
    ];
    let b = Bassd::start(rig.path(), "default", &args, &rig.env());
    let waiting = eventually("Status saying what the broker waits for", || {
        let s = b.client().status().ok()?;
        s.message.starts_with("waiting for device \"bass_jack\"").then_some(s)
    });
    assert_eq!(waiting.state, State::Idle as u32, "{waiting:?}");
    assert!(waiting.message.contains("next try in"), "{}", waiting.message);
    // A few tries fail while no jackd runs.
    std::thread::sleep(Duration::from_millis(1600));
    let _jackd = rig.jackd(RATE);
    let s = eventually("the configured acquisition capturing after jackd started", || {
        let s = b.client().status().ok()?;
        (s.state == State::Capturing as u32).then_some(s)
    });
    assert_eq!((s.epoch, s.device.as_str()), (1, "bass_jack"));
    let port = b.port();
    wait_frame(&port, 4800);
    let log = b.log_text();
    assert!(log.contains("did not start") && log.contains("next try in"), "{log}");
    assert!(log.contains("the configured acquisition of \"bass_jack\" started"), "{log}");
}

/// A mistyped card in the configuration is retried and named in Status, the broker up.
#[test]
fn a_configured_device_that_does_not_exist_is_named_in_status_and_retried() {
    let dir = TempDir::new("typo");
    let args = ["--acquire", "hw:97,0"];
    let mut b = Bassd::start(dir.path(), "default", &args, &[]);
    let s = eventually("Status naming the missing device", || {
        let s = b.client().status().ok()?;
        (s.message.starts_with("waiting for device \"hw:97,0\"") && s.message.contains("attempt 3"))
            .then_some(s)
    });
    assert_eq!(s.state, State::Idle as u32);
    assert!(b.is_running());
    // An operator's Acquire takes over: no more tries.
    b.client().acquire(&acquire_req("sim:pattern", 48000, 480, 100, 2)).unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let s = b.client().status().unwrap();
    assert_eq!((s.state, s.device.as_str()), (State::Capturing as u32, "sim:pattern"), "{s:?}");
    assert!(b.log_text().contains("no longer tried"), "{}", b.log_text());
}
