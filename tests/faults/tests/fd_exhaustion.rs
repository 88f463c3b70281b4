//! bassd out of file descriptors. With RLIMIT_NOFILE lowered to 40 (prlimit
//! on the running broker) and 60 control connections opened, `accept` fails with EMFILE.
//!
//! Pass: bassd stays alive and keeps capturing (lastFrameIndex advances), every connection is
//! either served or refused with the "out of file descriptors" message (none hangs), and a
//! new client is served once the others close. (Before the fix, bassd exited on the first
//! EMFILE, leaving its port "capturing".)

use std::sync::mpsc;
use std::time::Duration;

use bass_faults::{fd_count, figure};
use bass_test_support::{wait_until, Bassd, TempDir};
use bassport::control::Client;

const LIMIT: u64 = 40;
const CONNECTIONS: usize = 60;

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn running_out_of_descriptors_refuses_connections_and_recovers_while_capture_goes_on() {
    let dir = TempDir::shm("emfile");
    let args = ["--acquire", "sim:pattern", "--rate", "48000", "--frames", "480", "--chunks", "20"];
    let mut b = Bassd::start_stock(dir.path(), "fd", &args, &[]);
    // The acquisition's own descriptors are open before the limit is set.
    let port = b.port_once_acquired();
    let pid = b.pid();
    let fds_before = fd_count(pid);
    assert!((fds_before as u64) < LIMIT - 10, "bassd already has {fds_before} descriptors");
    let lim = rustix::process::Rlimit { current: Some(LIMIT), maximum: Some(LIMIT) };
    rustix::process::prlimit(
        rustix::process::Pid::from_raw(pid as i32),
        rustix::process::Resource::Nofile,
        lim,
    )
    .expect("prlimit on bassd");

    // Open the connections on a helper thread, so that a hang fails the test instead of blocking it.
    let (tx, rx) = mpsc::channel();
    let sock = b.socket();
    std::thread::spawn(move || {
        let mut held = Vec::new();
        let mut refusals = Vec::new();
        for _ in 0..CONNECTIONS {
            match Client::connect_path(&sock, "fd").and_then(|mut c| c.status().map(|_| c)) {
                Ok(c) => held.push(c),
                Err(e) => refusals.push(e.to_string()),
            }
        }
        tx.send((held, refusals)).expect("the test waits for the connections");
    });
    let (held, refusals) = rx.recv_timeout(Duration::from_secs(60)).expect("the 60 connections hung");
    assert!(b.is_running(), "bassd exited when descriptors ran out");
    assert!(!refusals.is_empty(), "the descriptor limit was never reached ({} served)", held.len());
    for r in &refusals {
        assert!(r.contains("out of file descriptors"), "unexpected refusal: {r}");
    }
    // Capture goes on while descriptors are exhausted.
    let lfi0 = port.info().unwrap().last_frame_index;
    let advanced =
        wait_until(Duration::from_secs(20), || port.info().unwrap().last_frame_index > lfi0 + 4800);
    assert!(advanced, "lastFrameIndex stuck at {lfi0} while out of descriptors");
    let lfi1 = port.info().unwrap().last_frame_index;
    // A client is refused clearly while the others hold their connections ...
    let during = Client::connect_path(&b.socket(), "fd").and_then(|mut c| c.status());
    assert!(during.is_err(), "a client was served while descriptors were exhausted");
    // ... and served once they close.
    let served_n = held.len();
    drop(held);
    let recovered = wait_until(Duration::from_secs(20), || {
        Client::connect_path(&b.socket(), "fd").and_then(|mut c| c.status()).is_ok()
    });
    assert!(recovered, "no client was served after the connections closed");
    let s = b.client().status().unwrap();
    assert_eq!(s.epoch, 1, "the capture was restarted");
    figure!(
        "9.2",
        "RLIMIT_NOFILE {LIMIT}, {CONNECTIONS} connections: {served_n} served, {} refused ({:?}); bassd alive; \
         lastFrameIndex {lfi0} -> {lfi1} while exhausted; a new client served after they closed (lastFrameIndex {})",
        refusals.len(),
        refusals.first().map(|r| r.chars().take(80).collect::<String>()).unwrap_or_default(),
        s.last_frame_index
    );
}
