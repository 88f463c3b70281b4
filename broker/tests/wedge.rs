//! No device path can wedge bassd, and a port cut under it is an error in Status: real
//! brokers, a real FIFO, a real jackd stopped with SIGSTOP behind ALSA's `jack` plugin, a real
//! port file truncated under the broker.
//!
//! Timing appears only as bounds with a wide margin over what was measured (docs/broker.md,
//! "Bounded device opens"); the measured numbers are printed for the record.

use std::time::{Duration, Instant};

use bass_test_support::*;
use bassport::control::Client;
use bassport::format::{error_code, State};

/// SIGTERM must end bassd within this (the goal is 1 s; the bound leaves room for a loaded
/// 2-core test machine, and the measured time is printed).
const SIGTERM_BOUND: Duration = Duration::from_millis(1500);

/// A control client that gives up after 3 s (so a wedged broker fails the test instead of
/// hanging it).
fn impatient(b: &Bassd) -> Client {
    let mut c = b.client();
    c.set_timeout(Duration::from_secs(3)).unwrap();
    c
}

/// Sends SIGTERM and returns how long bassd took to exit (panics past [`PATIENCE`]).
fn sigterm_time(b: &mut Bassd) -> Duration {
    let t = Instant::now();
    b.signal(libc::SIGTERM);
    let st = b.wait_exit();
    let took = t.elapsed();
    assert!(st.success(), "bassd exited with {st} after SIGTERM; log:\n{}", b.log_text());
    took
}

#[test]
fn a_fifo_as_sim_file_is_refused_at_once_status_answers_and_sigterm_ends_bassd() {
    let dir = TempDir::new("wedge-fifo");
    let fifo = dir.join("rec.wav");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("run mkfifo");
    assert!(made.success(), "mkfifo {}", fifo.display());
    let mut b = Bassd::start_replaying(dir.path(), "fifo");
    let mut c = impatient(&b);
    let device = format!("sim:file:{}", fifo.display());
    let t = Instant::now();
    let e = c.acquire(&acquire_req(&device, 48000, 480, 100, 2)).expect_err("a FIFO is refused");
    let refused_in = t.elapsed();
    let msg = e.to_string();
    assert!(msg.contains("is a FIFO") && msg.ends_with("[device]"), "{msg}");
    let s = c.status().expect("Status answers after the refusal");
    assert_eq!(s.state, State::Idle as u32, "nothing was acquired: {s:?}");
    let took = sigterm_time(&mut b);
    eprintln!("FIFO refused in {refused_in:?}; SIGTERM ended bassd in {took:?}");
    assert!(refused_in < Duration::from_secs(2), "the FIFO refusal took {refused_in:?}");
    assert!(took < SIGTERM_BOUND, "SIGTERM took {took:?}");
}

/// ALSA's jack plugin against a jackd stopped with SIGSTOP: `snd_pcm_open` connects and
/// waits for the server's answer forever (found by experiment: `arecord -D bass_jack` hangs
/// in the open). The broker must bound the open, answer Status meanwhile (state starting,
/// naming the device), refuse the Acquire with a device error naming the device and the
/// time waited, keep the running acquisition's port as it was, and end on SIGTERM promptly
/// even while an open is stuck.
#[test]
fn an_alsa_open_that_never_returns_is_bounded_status_answers_and_sigterm_ends_bassd() {
    if skip(jack_missing()) {
        return;
    }
    let rig = JackRig::new(TempDir::new("wedge-jack"), "bass-test-wedge");
    let jackd = rig.jackd(48000);
    let mut b = Bassd::start(rig.path(), "wedge", &["--allow-device", "bass_jack"], &rig.env());
    // A running acquisition whose port must come through the failed Acquire untouched.
    let mut c = impatient(&b);
    let before = c.acquire(&acquire_req("sim:sine", 48000, 480, 100, 2)).unwrap();
    wait_frame(&b.port(), 4800);
    send_signal(jackd_pid(&rig), libc::SIGSTOP);

    let (sock, name) = (b.socket(), b.name.clone());
    let t = Instant::now();
    let acquirer = std::thread::spawn(move || {
        let mut c = Client::connect_path(&sock, &name).unwrap();
        c.set_timeout(Duration::from_secs(15)).unwrap();
        let r = c.acquire(&acquire_req("bass_jack", 48000, 480, 100, 2));
        (r, t.elapsed())
    });
    // Status answers while the open hangs, and says what is going on.
    let s = eventually("Status to show the open in progress", || {
        let s = c.status().expect("Status answers while a device open hangs");
        (s.state == State::Starting as u32).then_some(s)
    });
    assert!(s.message.contains("bass_jack"), "Status names the device being opened: {s:?}");
    let t_status = Instant::now();
    let s2 = c.status().expect("Status again");
    let status_latency = t_status.elapsed();
    assert_eq!(s2.state, State::Starting as u32, "{s2:?}");
    // A second Acquire meanwhile is refused at once, naming the pending one.
    let e = c.acquire(&acquire_req("sim:sine", 48000, 480, 100, 2)).expect_err("refused while opening");
    assert!(e.to_string().contains("bass_jack"), "{e}");

    let (r, waited) = acquirer.join().unwrap();
    let msg = r.expect_err("the stuck open ends in an error").to_string();
    eprintln!("stuck open refused after {waited:?}: {msg}");
    assert!(msg.ends_with("[device]") && msg.contains("bass_jack"), "{msg}");
    assert!(msg.contains("did not return within"), "the error says the open timed out: {msg}");
    // The old port is exactly as it was: same epoch, still capturing.
    let s = c.status().unwrap();
    assert_eq!((s.epoch, s.state), (before.epoch, State::Capturing as u32), "{s:?}");

    // Another open that hangs, cancelled by a Stop: the parked Acquire gets an error at once.
    let (sock, name) = (b.socket(), b.name.clone());
    let parked = std::thread::spawn(move || {
        let mut c = Client::connect_path(&sock, &name).unwrap();
        c.set_timeout(Duration::from_secs(15)).unwrap();
        c.acquire(&acquire_req("bass_jack", 48000, 480, 100, 2))
    });
    eventually("the open to start", || {
        (c.status().expect("Status answers").state == State::Starting as u32).then_some(())
    });
    let stopped = c.stop_report().expect("Stop answers while a device open hangs");
    assert!(stopped.contains("cancelled the Acquire of \"bass_jack\""), "{stopped}");
    let e = parked.join().unwrap().expect_err("the cancelled Acquire gets an error").to_string();
    assert!(e.contains("cancelled by a Stop") && e.ends_with("[device]"), "{e}");
    let s = c.status().unwrap();
    assert_eq!((s.epoch, s.state), (before.epoch, State::Stopped as u32), "{s:?}");

    // Another open that hangs, then SIGTERM in the middle of it.
    let (sock, name) = (b.socket(), b.name.clone());
    let parked = std::thread::spawn(move || {
        let mut c = Client::connect_path(&sock, &name).unwrap();
        c.set_timeout(Duration::from_secs(15)).unwrap();
        c.acquire(&acquire_req("bass_jack", 48000, 480, 100, 2))
    });
    eventually("the second open to start", || {
        (c.status().expect("Status answers").state == State::Starting as u32).then_some(())
    });
    drop(c);
    let took = sigterm_time(&mut b);
    let r = parked.join().unwrap();
    assert!(r.is_err(), "the parked Acquire got {r:?}");
    eprintln!(
        "Status answered in {status_latency:?} during a stuck open; SIGTERM ended bassd in {took:?} \
         with three device opens stuck"
    );
    assert!(took < SIGTERM_BOUND, "SIGTERM took {took:?}; log:\n{}", b.log_text());
    send_signal(jackd_pid(&rig), libc::SIGCONT);
    drop(jackd);
}

/// `--open-timeout-ms` bounds the open, and threads left stuck in a device are capped: once
/// [`bassd::server::MAX_STUCK_OPENS`] opens never returned, Acquires are refused at once
/// instead of piling up threads; other requests and devices' Status still answer.
#[test]
fn stuck_device_opens_are_bounded_by_the_option_and_capped_in_number() {
    if skip(jack_missing()) {
        return;
    }
    let rig = JackRig::new(TempDir::new("wedge-cap"), "bass-test-wedge-cap");
    let jackd = rig.jackd(48000);
    let args = ["--allow-device", "bass_jack", "--open-timeout-ms", "300"];
    let mut b = Bassd::start(rig.path(), "wedge-cap", &args, &rig.env());
    let mut c = impatient(&b);
    send_signal(jackd_pid(&rig), libc::SIGSTOP);
    for _ in 0..bassd::server::MAX_STUCK_OPENS {
        let t = Instant::now();
        let e = c.acquire(&acquire_req("bass_jack", 48000, 480, 100, 2)).expect_err("times out").to_string();
        let waited = t.elapsed();
        assert!(e.contains("did not return within") && e.contains("--open-timeout-ms 300"), "{e}");
        assert!(waited >= Duration::from_millis(300), "answered after {waited:?}, before the bound");
    }
    let t = Instant::now();
    let e = c.acquire(&acquire_req("bass_jack", 48000, 480, 100, 2)).expect_err("refused").to_string();
    assert!(e.contains("earlier device opens never returned") && e.ends_with("[device]"), "{e}");
    assert!(t.elapsed() < Duration::from_millis(300), "the capped refusal is immediate: {:?}", t.elapsed());
    assert_eq!(c.status().unwrap().state, State::Idle as u32);
    // The stuck opens return once jackd runs again; then the broker opens devices again.
    send_signal(jackd_pid(&rig), libc::SIGCONT);
    let a = eventually("an Acquire once jackd runs again", || {
        c.acquire(&acquire_req("sim:sine", 48000, 480, 100, 2)).ok()
    });
    assert_eq!(a.epoch, 1);
    drop(c);
    let took = sigterm_time(&mut b);
    assert!(took < SIGTERM_BOUND, "SIGTERM took {took:?}");
    drop(jackd);
}

/// SIGTERM while capturing from a jackd that was stopped under the capture (the capture
/// thread waits inside the jack plugin): bassd still ends promptly, leaving the thread behind.
#[test]
fn sigterm_ends_bassd_promptly_while_its_capture_waits_in_a_stopped_sound_server() {
    if skip(jack_missing()) {
        return;
    }
    let rig = JackRig::new(TempDir::new("wedge-read"), "bass-test-wedge-read");
    let jackd = rig.jackd(48000);
    let mut b = Bassd::start(rig.path(), "wedge-read", &["--allow-device", "bass_jack"], &rig.env());
    let mut c = impatient(&b);
    c.acquire(&acquire_req("bass_jack", 48000, 480, 100, 2)).unwrap();
    wait_frame(&b.port(), 4800);
    send_signal(jackd_pid(&rig), libc::SIGSTOP);
    // The stall watchdog (1.5 s in the rig) ends the acquisition; the thread stays in the plugin.
    let s = eventually("the stall to be reported", || {
        let s = c.status().expect("Status answers while the device is stuck");
        (s.state == State::Error as u32).then_some(s)
    });
    assert_eq!(s.error_code, error_code::DEVICE_STALLED, "{s:?}");
    drop(c);
    let took = sigterm_time(&mut b);
    eprintln!("SIGTERM ended bassd in {took:?} with its capture thread waiting in a stopped jackd");
    assert!(took < SIGTERM_BOUND, "SIGTERM took {took:?}; log:\n{}", b.log_text());
    send_signal(jackd_pid(&rig), libc::SIGCONT);
    drop(jackd);
}

/// The pid of the rig's jackd (by its server name on the command line).
fn jackd_pid(rig: &JackRig) -> u32 {
    let want = format!("-n\0{}\0", rig.jack_name);
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else { continue };
        let Ok(cmd) = std::fs::read(e.path().join("cmdline")) else { continue };
        let cmd = String::from_utf8_lossy(&cmd);
        if cmd.starts_with("jackd\0") && cmd.contains(&want) {
            return pid;
        }
    }
    panic!("no jackd -n {} running", rig.jack_name);
}

/// A port file truncated under the broker: the capture fails at its next publish, and
/// Status must say so (state error, a message) instead of the port's stale "capturing" —
/// whether the cut kept the header page (the broker's own view of the port still reads a
/// plausible header) or took the whole file (the broker cannot read the port at all).
#[test]
fn a_port_cut_under_bassd_is_an_error_in_status_within_a_chunk_or_two() {
    let dir = TempDir::new("wedge-cut");
    let b = Bassd::start(dir.path(), "cut", &[], &[]);
    let mut c = impatient(&b);
    for cut in [4096, 0] {
        // 10 ms chunks.
        c.acquire(&acquire_req("sim:sine", 48000, 480, 100, 2)).unwrap();
        wait_frame(&b.port(), 4800);
        assert_eq!(c.status().unwrap().state, State::Capturing as u32);
        let f = std::fs::OpenOptions::new().write(true).open(b.port_path()).unwrap();
        let t = Instant::now();
        f.set_len(cut).unwrap();
        let s = eventually("Status to report the cut port", || {
            let s = c.status().expect("Status answers");
            (s.state == State::Error as u32).then_some(s)
        });
        let latency = t.elapsed();
        eprintln!("port cut to {cut} bytes: Status reported it after {latency:?}: {}", s.message);
        assert_ne!(s.error_code, error_code::NONE, "{s:?}");
        assert!(s.message.contains("shrank"), "the message says what happened: {s:?}");
        assert!(latency < Duration::from_secs(1), "Status took {latency:?} to report the cut (10 ms chunks)");
        // It stays an error (not a flicker).
        std::thread::sleep(Duration::from_millis(100));
        assert_eq!(c.status().unwrap().state, State::Error as u32);
    }
}
