//! Every service through the control socket, bad requests, the raw protocol, named brokers,
//! and the lifecycle (second instance, killed broker, SIGTERM).

use std::os::fd::AsFd;
use std::process::Command;

use bass_test_support::*;
use basskit::testsignal::pattern_sample;
use bassport::control;
use bassport::format::State;
use bassport::Error;

#[test]
fn every_service_works_through_the_socket() {
    let dir = TempDir::new("services");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();

    let devices = c.list_devices().unwrap();
    for sim in ["sim:pattern", "sim:sine", "sim:xrun", "sim:stall"] {
        let d = devices.iter().find(|d| d.name == sim).unwrap_or_else(|| panic!("{sim} not listed"));
        assert!(d.description.starts_with("Simulated"), "{d:?}");
    }

    let s = c.status().unwrap();
    assert_eq!((s.state, s.epoch, s.last_frame_index), (State::Idle as u32, 0, 0));
    assert_eq!(s.broker_pid, b.pid());

    let a = c.acquire(&acquire_req("sim:pattern", 16000, 160, 20, 2)).unwrap();
    assert_eq!(a.epoch, 1);
    assert_eq!(a.port, b.port_path());
    let port = b.port();
    wait_frame(&port, 320);
    let s = c.status().unwrap();
    assert_eq!(s.state, State::Capturing as u32);
    assert_eq!((s.sample_rate, s.frames_per_chunk, s.chunks_on_port, s.channels), (16000, 160, 20, 2));
    assert_eq!((s.epoch, s.device.as_str(), s.format.as_str()), (1, "sim:pattern", "S32_LE"));
    assert!(s.last_frame_index >= 320 && s.last_frame_index % 160 == 0);

    c.stop().unwrap();
    let s = c.status().unwrap();
    assert_eq!(s.state, State::Stopped as u32);
    assert!(matches!(port.wait(u64::MAX >> 8, PATIENCE), Err(Error::Stopped { .. })));
    let last = port.info().unwrap().last_frame_index;
    assert_eq!(read_frames(&port, last, last)[1][0], pattern_sample(last, 1));
    // Stop is idempotent; Acquire after Stop starts a new epoch.
    c.stop().unwrap();
    assert_eq!(c.acquire(&acquire_req("sim:pattern", 16000, 160, 20, 2)).unwrap().epoch, 2);
}

#[test]
fn acquire_while_acquiring_restarts_with_the_new_parameters() {
    let dir = TempDir::new("restart");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap();
    let old = b.port();
    wait_frame(&old, 80);
    let a = c.acquire(&acquire_req("sim:sine", 48000, 480, 5, 1)).unwrap();
    assert_eq!(a.epoch, 2);
    assert!(matches!(old.wait(u64::MAX >> 8, PATIENCE), Err(Error::Restarted)));
    let new = b.port();
    assert_eq!(new.epoch(), 2);
    assert_eq!((new.geometry().sample_rate, new.geometry().channels), (48000, 1));
}

/// Bad requests are refused with a message naming the problem; the running acquisition
/// keeps running (same epoch, frames keep coming).
#[test]
fn bad_requests_are_refused_and_the_running_acquisition_continues() {
    let dir = TempDir::new("bad");
    let b = Bassd::start(dir.path(), "default", &["--max-port-bytes", "10000000"], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap();
    let port = b.port();
    let mut with_format = acquire_req("sim:pattern", 8000, 80, 10, 2);
    with_format.format = Some("U8".into());
    let cases = [
        (acquire_req("sim:pattern", 8000, 0, 10, 2), "nFramesPerChunk = 0"),
        (acquire_req("sim:pattern", 8000, 80, 0, 2), "nChunksOnPort = 0"),
        (acquire_req("sim:pattern", 0, 80, 10, 2), "sampleRate = 0"),
        (acquire_req("sim:pattern", 8000, 80, 10, 0), "channels = 0"),
        (acquire_req("sim:pattern", 8000, 80, 10, 65), "channels = 65"),
        (acquire_req("sim:pattern", 8000, u32::MAX, u32::MAX, 64), "exceeds the format's limit"),
        (acquire_req("sim:pattern", 8000, 100_000, 100, 2), "memory cap of 10000000 bytes"),
        (acquire_req("sim:nosuch", 8000, 80, 10, 2), "unknown simulated device \"sim:nosuch\""),
        (acquire_req("", 8000, 80, 10, 2), "device name is empty"),
        (with_format, "unknown sample format \"U8\""),
    ];
    for (r, want) in cases {
        match c.acquire(&r) {
            Err(Error::Broker(m)) => {
                assert!(m.contains(want), "{r:?}: {m:?} does not say {want:?}");
                assert!(m.ends_with("[invalid-argument]"), "{m}");
            }
            other => panic!("{r:?} was not refused: {other:?}"),
        }
        let last = port.info().unwrap().last_frame_index;
        wait_frame(&port, last + 80);
    }
    let s = c.status().unwrap();
    assert_eq!((s.state, s.epoch), (State::Capturing as u32, 1));
}

/// A device that fails to open is refused before the running acquisition is touched: the
/// old port keeps capturing in its epoch, and a later Acquire works.
#[test]
fn an_unknown_alsa_device_leaves_the_running_port_untouched_and_a_later_acquire_works() {
    let dir = TempDir::new("nodev");
    // Not a card reference: the device policy would refuse it before ALSA sees it.
    let b = Bassd::start(dir.path(), "default", &["--allow-device", "bass_no_such_pcm"], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap();
    let old = b.port();
    let e = c.acquire(&acquire_req("bass_no_such_pcm", 8000, 80, 10, 2)).unwrap_err();
    assert!(
        matches!(&e, Error::Broker(m) if m.contains("bass_no_such_pcm") && m.contains("the port is unchanged (epoch 1")
            && m.ends_with("[device]")),
        "{e}"
    );
    let lfi = old.info().unwrap().last_frame_index;
    assert!(old.wait(lfi + 80, PATIENCE).is_ok(), "the old acquisition stopped");
    assert_eq!(b.port().epoch(), 1);
    let s = c.status().unwrap();
    assert_eq!((s.state, s.error_code, s.epoch), (State::Capturing as u32, 0, 1));
    assert_eq!(c.acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap().epoch, 2);
}

#[test]
fn the_protocol_refuses_other_versions_and_garbage() {
    let dir = TempDir::new("proto");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    let code = |r: control::Reply| match r {
        control::Reply::Error { kind, .. } => kind,
        other => panic!("expected an error reply, got {other:?}"),
    };
    let r = c.call_raw(br#"{"version":"bass-control/3","request":"status"}"#).unwrap();
    assert_eq!(code(r), control::ErrorKind::Version);
    let r = c.call_raw(br#"{"version":"bass-control/2","request":"frobnicate"}"#).unwrap();
    assert_eq!(code(r), control::ErrorKind::Protocol);
    let r = c.call_raw(br#"{"version":"bass-control/2","request":"acquire","sample_rate":"fast"}"#).unwrap();
    assert_eq!(code(r), control::ErrorKind::Protocol);
    // Raw bytes that are not a message at all, on a fresh connection.
    let fd = control::socket::connect(&b.socket()).unwrap();
    control::send_datagram(fd.as_fd(), b"hello\n").unwrap();
    let r = control::recv_reply(fd.as_fd()).unwrap().unwrap();
    assert_eq!(code(r), control::ErrorKind::Protocol);
    // A version-1 client (key=value text) is answered in its own form, naming both versions.
    let fd = control::socket::connect(&b.socket()).unwrap();
    control::send_datagram(fd.as_fd(), b"bass-control/1 status\n").unwrap();
    let r = control::recv_datagram(fd.as_fd()).unwrap().unwrap();
    let text = String::from_utf8(r).unwrap();
    assert!(text.starts_with("bass-control/1 error\ncode=version\nmessage="), "{text}");
    assert!(text.contains("bass-control/2") && text.contains("bass-control/1"), "{text}");
    // The broker is still fine.
    assert_eq!(c.status().unwrap().state, State::Idle as u32);
}

#[test]
fn two_named_brokers_coexist() {
    let dir = TempDir::new("named");
    let a = Bassd::start(dir.path(), "left", &[], &[]);
    let b = Bassd::start(dir.path(), "right", &[], &[]);
    a.client().acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap();
    b.client().acquire(&acquire_req("sim:silence", 16000, 160, 10, 1)).unwrap();
    let (pa, pb) = (a.port(), b.port());
    assert_ne!(a.port_path(), b.port_path());
    wait_frame(&pa, 160);
    wait_frame(&pb, 160);
    assert_eq!(read_frames(&pa, 160, 160)[0][0], pattern_sample(160, 0));
    assert_eq!(read_frames(&pb, 1, 160), vec![vec![0; 160]]);
    a.client().stop().unwrap();
    assert_eq!(a.client().status().unwrap().state, State::Stopped as u32);
    assert_eq!(b.client().status().unwrap().state, State::Capturing as u32);
}

#[test]
fn a_second_bassd_with_the_same_name_refuses_to_start() {
    let dir = TempDir::new("second");
    let first = Bassd::start(dir.path(), "default", &[], &[]);
    let out = Command::new(bassd_bin()).env("BASS_RUNTIME_DIR", dir.path()).output().expect("run bassd");
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("a broker named \"default\" is already running"), "{err}");
    assert!(err.contains(&format!("pid {}", first.pid())), "{err}");
    // The first one is unaffected.
    assert_eq!(first.client().status().unwrap().broker_pid, first.pid());
}

#[test]
fn a_killed_brokers_socket_and_port_are_replaced_safely() {
    let dir = TempDir::new("stale");
    let mut b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap();
    let port = b.port();
    wait_frame(&port, 80);
    b.signal(libc::SIGKILL);
    b.wait_exit();
    assert!(b.socket().exists(), "a killed broker leaves its socket");
    assert!(matches!(port.wait(u64::MAX >> 8, PATIENCE), Err(Error::WriterGone { .. })));
    assert!(matches!(b.try_client(), Err(Error::NoBroker { .. })));
    let b2 = Bassd::start(dir.path(), "default", &[], &[]);
    assert!(b2.log_text().contains("stale control socket"), "{}", b2.log_text());
    let a = b2.client().acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap();
    assert_eq!(a.epoch, 2, "the epoch continues from the dead broker's port");
    let p2 = b2.port();
    wait_frame(&p2, 80);
    assert_eq!(read_frames(&p2, 80, 80)[0][0], pattern_sample(80, 0));
}

#[test]
fn sigterm_stops_the_capture_marks_the_port_stopped_and_removes_the_socket() {
    for sig in [libc::SIGTERM, libc::SIGINT] {
        let dir = TempDir::new("sigterm");
        let mut b = Bassd::start(dir.path(), "default", &[], &[]);
        b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap();
        let port = b.port();
        wait_frame(&port, 80);
        let waiter = std::thread::spawn({
            let path = b.port_path();
            move || bassport::Port::open_path(&path).unwrap().wait(u64::MAX >> 8, PATIENCE)
        });
        b.signal(sig);
        assert!(b.wait_exit().success());
        assert!(matches!(waiter.join().unwrap(), Err(Error::Stopped { .. })));
        assert_eq!(port.info().unwrap().state, Some(State::Stopped));
        assert!(!b.socket().exists());
        assert!(matches!(b.try_client(), Err(Error::NoBroker { .. })));
    }
}

#[test]
fn clients_of_another_user_are_refused_by_peer_credentials() {
    // Needs root (and setpriv) to run a client as another user; elsewhere the socket's mode
    // already refuses. Under BASS_TESTS_NO_SKIP (CI) a missing one fails instead of skipping.
    if skip(impersonation_missing()) {
        return;
    }
    let dir = TempDir::new("peercred");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    // Open the file modes so that only the broker's own check stands in the way.
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    std::fs::set_permissions(b.socket(), std::fs::Permissions::from_mode(0o666)).unwrap();
    let out = Command::new("setpriv")
        .args(["--reuid=65534", "--regid=65534", "--clear-groups", &bass_bin(), "status"])
        .env("BASS_RUNTIME_DIR", dir.path())
        .output();
    let out = out.expect("setpriv runs (impersonation_missing checked it)");
    let err = String::from_utf8_lossy(&out.stderr);
    if err.contains("Permission denied (os error 13)") && err.contains("bass-default.sock") {
        eprintln!("skipped: the bass binary or the socket path is not reachable as nobody: {err}");
        return;
    }
    assert!(!out.status.success());
    assert!(err.contains("permission denied: not the broker's user or group"), "{err}");
    assert_eq!(b.client().status().unwrap().state, State::Idle as u32);
}

#[test]
fn members_of_the_configured_group_are_served() {
    if skip(impersonation_missing()) {
        return;
    }
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let dir = TempDir::new("group");
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    let b = Bassd::start(dir.path(), "default", &["--group", "65534"], &[]);
    let sock = std::fs::metadata(b.socket()).unwrap();
    assert_eq!((sock.mode() & 0o777, sock.gid()), (0o660, 65534));
    // uid 65534 is neither the broker's user nor root: only its group lets it in.
    let out = Command::new("setpriv")
        .args(["--reuid=65534", "--regid=65534", "--clear-groups", &bass_bin(), "acquire", "sim:pattern"])
        .args(["--rate", "8000", "--frames", "80", "--chunks", "10"])
        .env("BASS_RUNTIME_DIR", dir.path())
        .output();
    let out = out.expect("setpriv runs (impersonation_missing checked it)");
    let err = String::from_utf8_lossy(&out.stderr);
    if err.contains("Permission denied (os error 13)") {
        eprintln!("skipped: the bass binary is not reachable as nobody: {err}");
        return;
    }
    assert!(out.status.success(), "{err}");
    let port = std::fs::metadata(b.port_path()).unwrap();
    assert_eq!((port.mode() & 0o777, port.gid()), (0o640, 65534));
    assert_eq!(b.client().status().unwrap().epoch, 1);
}

/// A user outside the broker's group is refused the socket (0660) and the port (0640) by the
/// system, not by the broker: told so, and how to join the group, never "is bassd running?
/// Start it" (it is running). A user whose login predates the membership is told to log in
/// again.
#[test]
fn a_user_outside_the_group_is_told_to_join_it_not_to_start_bassd() {
    if skip(impersonation_missing()) {
        return;
    }
    use std::os::unix::fs::PermissionsExt;
    let dir = TempDir::new("not-in-group");
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    let b = Bassd::start(dir.path(), "default", &["--group", "65534"], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap();
    wait_frame(&b.port(), 80);
    let sock = b.socket().display().to_string();
    let port = b.port_path().display().to_string();
    // uid 4242 has no passwd entry and no group; nobody (65534) has group 65534 as its primary
    // group in /etc/passwd, but not in this process (--regid=4242).
    let run = |uid: &str, args: &[&str]| {
        let who = [format!("--reuid={uid}"), "--regid=4242".into(), "--clear-groups".into()];
        let o = setpriv(&who, bass_bin()).args(args).env("BASS_RUNTIME_DIR", dir.path()).output().unwrap();
        (o.status.code(), String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let (code, err) = run("4242", &["status"]);
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("permission denied: you are not in the group "), "{err}");
    assert!(err.contains(&format!("(the socket {sock} is 0660 root:")), "{err}");
    assert!(err.contains(": sudo adduser $USER ") && err.contains(", then log in again"), "{err}");
    assert!(!err.contains("is bassd") && !err.contains("Start it"), "{err}");
    let (code, err) = run("4242", &["blocks", "-n", "1"]);
    assert_ne!(code, Some(0), "{err}");
    assert!(err.contains(&format!("(the port {port} is 0640 root:")), "{err}");
    assert!(err.contains("sudo adduser $USER ") && !err.contains("Permission denied (os error 13)"), "{err}");
    assert_eq!(err.matches("permission denied").count(), 1, "said once: {err}");
    let (code, err) = run("65534", &["status"]);
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("this login session is not in the group ") && err.contains("log in again"), "{err}");
    assert_eq!(b.client().status().unwrap().state, State::Capturing as u32);
}

/// The request that starved a core (768 kHz, 1-frame chunks, 64 channels)
/// is refused by the default bounds, each bound named with the option that widens it; a
/// broker started with wider bounds accepts it. Nothing changes on a refusal.
#[test]
fn operator_bounds_refuse_a_starving_request_until_widened() {
    let dir = TempDir::new("bounds");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap();
    let cases = [
        (
            acquire_req("sim:pattern", 768_000, 1, 4096, 64),
            "above this broker's limit of 192000 Hz (bassd --max-rate)",
        ),
        (
            acquire_req("sim:pattern", 192_000, 1, 4096, 64),
            "above this broker's limit of 32 (bassd --max-channels)",
        ),
        (
            acquire_req("sim:pattern", 192_000, 1, 4096, 2),
            "minimum chunk duration of 500 µs (bassd --min-chunk-us)",
        ),
        (
            acquire_req("sim:pattern", 8000, 8000, 3601, 1),
            "above this broker's limit of 3600 s (bassd --max-window-s)",
        ),
    ];
    for (r, want) in &cases {
        let e = c.acquire(r).unwrap_err().to_string();
        assert!(e.contains(want) && e.ends_with("[invalid-argument]"), "{r:?}: {e}");
    }
    assert_eq!(c.status().unwrap().epoch, 1, "a refused request changed the acquisition");
    drop(c);
    drop(b);
    let wide = ["--max-rate", "768000", "--max-channels", "64", "--min-chunk-us", "0"];
    let b = Bassd::start(dir.path(), "wide", &wide, &[]);
    let mut c = b.client();
    let a = c.acquire(&acquire_req("sim:pattern", 768_000, 1, 4096, 64)).unwrap();
    assert_eq!(a.epoch, 1);
    c.stop().unwrap();
}

/// A control connection with no request for the idle timeout is closed
/// (128 idle connections no longer lock everyone out), and the library's client reconnects
/// transparently when its own idle connection was closed.
#[test]
fn idle_control_connections_are_closed_and_clients_reconnect() {
    let dir = TempDir::new("idle");
    let b = Bassd::start(dir.path(), "default", &["--idle-timeout-ms", "200"], &[]);
    let mut c = b.client();
    c.status().unwrap();
    let raw = control::seqpacket_socket().unwrap();
    rustix::net::connect(&raw, &rustix::net::SocketAddrUnix::new(b.socket()).unwrap()).unwrap();
    // The broker closes the idle connection: its next read sees the end (bounded wait).
    let slice = Some(std::time::Duration::from_millis(100));
    rustix::net::sockopt::set_socket_timeout(&raw, rustix::net::sockopt::Timeout::Recv, slice).unwrap();
    let closed =
        eventually("the idle connection to be closed", || match control::recv_datagram(raw.as_fd()) {
            Ok(None) => Some(true),
            Ok(Some(m)) => panic!("unexpected message {:?}", String::from_utf8_lossy(&m)),
            Err(_) => None,
        });
    assert!(closed);
    // `c` was idle as long: its next request goes through a fresh connection.
    assert_eq!(c.status().unwrap().state, State::Idle as u32);
    assert_eq!(c.acquire(&acquire_req("sim:pattern", 8000, 80, 10, 2)).unwrap().epoch, 1);
}

/// An Acquire that interrupts a running acquisition is one Restarted for a stream that
/// follows it, never a Stopped first (a stream with no event callback ends at the first
/// event: it would end on some interrupting Acquires and not others).
#[test]
fn interrupting_acquires_are_each_one_restarted_and_never_a_stopped() {
    use bassport::stream::{Config, Control, Stream};
    use std::sync::{Arc, Mutex};
    let dir = TempDir::new("interrupt");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 8000, 80, 100, 2)).unwrap();
    let events = Arc::new(Mutex::new(Vec::new()));
    let e = events.clone();
    let handle = Stream::open_path(&b.port_path(), Config::default())
        .unwrap()
        .spawn(
            |_| Control::Continue,
            move |ev| {
                e.lock().unwrap().push(format!("{ev:?}"));
                Control::Continue
            },
        )
        .unwrap();
    for i in 0..20u64 {
        let a = c.acquire(&acquire_req("sim:pattern", 8000, 80, 100, 2)).unwrap();
        assert_eq!(a.epoch, i + 2);
        // The stream has followed this Acquire before the next one.
        eventually("the stream in the new epoch", || {
            events
                .lock()
                .unwrap()
                .iter()
                .any(|e| e.starts_with(&format!("Restarted {{ epoch: {}", i + 2)))
                .then_some(())
        });
    }
    drop(handle);
    let events = events.lock().unwrap();
    let want: Vec<String> = (2..22).map(|e| format!("Restarted {{ epoch: {e}, resume_at: 1 }}")).collect();
    assert_eq!(*events, want);
}

/// Voluntary context switches of one thread of `pid` so far (each is one wake-up after a
/// sleep).
fn voluntary_switches(pid: u32, tid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/task/{tid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("voluntary_ctxt_switches:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

/// While nothing is due, bassd's control loop sleeps up to 80 ms (it woke every 25 ms): a
/// count of its thread's sleeps over 2 s of steady capture with no client talking to it,
/// not a timing. The capture thread is untouched by this (its wakes are the device's).
#[test]
fn the_control_loop_sleeps_while_nothing_is_due() {
    let dir = TempDir::new("ticks");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 48000, 256, 64, 2)).unwrap();
    let port = b.port();
    wait_frame(&port, 4 * 256);
    drop(c);
    // The main thread's tid is the pid; let the dropped connection's close be handled.
    std::thread::sleep(std::time::Duration::from_millis(200));
    let before = voluntary_switches(b.pid(), b.pid());
    let first = port.info().unwrap().last_frame_index;
    std::thread::sleep(std::time::Duration::from_secs(2));
    let wakes = voluntary_switches(b.pid(), b.pid()) - before;
    let frames = port.info().unwrap().last_frame_index - first;
    // 2 s at one wake per 80 ms is 25; at 25 ms it was 80. A loaded machine makes sleeps
    // end later, never more of them.
    assert!(wakes <= 40, "the control loop woke {wakes} times in 2 s (at most 40 expected: an 80 ms tick)");
    // And it did not sleep through the capture: frames went on meanwhile.
    assert!(frames >= 48000, "only {frames} frames in 2 s while the control loop slept");
}
