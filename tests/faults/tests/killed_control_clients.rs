//! Item 3 (broker) — clients of a real `bassd` SIGKILLed: 100 port readers (50 mid-read,
//! 50 mid-wait) and 50 control clients in the middle of a request, while the broker
//! captures `sim:pattern` and a steady reader process follows the port.
//!
//! Pass: the broker carries on (same epoch, capturing, 0 xruns, 0 gap frames, answering);
//! the steady reader gets 0 corrupted samples and exact accounting; the broker's file
//! descriptors return to their count before the kills (no leaked control connections);
//! the runtime directory holds exactly what it held before (no leaked port or socket files).

use std::os::unix::process::ExitStatusExt;
use std::time::Duration;

use bass_faults::{fd_count, figure, Agent, Rng};
use bass_test_support::{acquire_req, Bassd, TempDir};

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn killed_readers_and_control_clients_leak_nothing_in_bassd() {
    let seed = bass_faults::seed();
    let mut rng = Rng::with_seed(seed);
    let dir = TempDir::shm("bclients");
    let b = Bassd::start_stock(dir.path(), "kc", &[], &[]);
    let mut c = b.client();
    let epoch = c.acquire(&acquire_req("sim:pattern", 48000, 480, 20, 2)).unwrap().epoch;
    let port = b.port_path();
    let p = port.to_str().unwrap();
    let mut steady = Agent::spawn(&["reader", "--port", p, "--mode", "wait", "--n", "480"]);
    steady.expect_line("ready");
    // The acquisition runs (device and capture thread up) before the broker's fds are counted.
    bass_test_support::eventually("the first chunks", || {
        c.status()
            .ok()
            .filter(|s| s.state() == Some(bassport::State::Capturing) && s.last_frame_index >= 4800)
    });
    let fds_before = fd_count(b.pid());
    let entries_before = dir.entries();
    let sock = b.socket();
    let s = sock.to_str().unwrap();
    let mut kinds = std::collections::BTreeMap::<&str, u32>::new();
    for i in 0..150 {
        let mut v = match i % 3 {
            0 => Agent::spawn(&["victim", "--port", p, "--mode", "read"]),
            1 => Agent::spawn(&["victim", "--port", p, "--mode", "wait"]),
            _ => Agent::spawn(&["control-victim", "--socket", s, "--name", "kc"]),
        };
        v.expect_line("ready");
        std::thread::sleep(Duration::from_micros(rng.u64(..5000)));
        v.signal(libc::SIGKILL);
        let (status, _) = v.finish();
        assert_eq!(status.signal(), Some(libc::SIGKILL));
        *kinds
            .entry(["reader mid-read", "reader mid-wait", "control client mid-request"][i % 3])
            .or_default() += 1;
    }
    let settled = bass_test_support::wait_until(Duration::from_secs(5), || fd_count(b.pid()) <= fds_before);
    let fds_after = fd_count(b.pid());
    let entries_after = dir.entries();
    let st = c.status().expect("broker answers");
    c.stop().unwrap();
    let rf = steady.result();
    figure!(
        3,
        "bassd: {kinds:?} SIGKILLed (seed {seed}); broker fds {fds_before} before, {fds_after} after; runtime dir {entries_before:?} -> {entries_after:?}; capture epoch {epoch} -> {}, state {:?}, xruns {}, gap frames {}; steady reader delivered={} lost={} corrupted={}",
        st.epoch,
        st.state(),
        st.xruns,
        st.gap_frames,
        rf.u("delivered"),
        rf.u("lost"),
        rf.u("corrupted")
    );
    assert!(settled, "bassd kept file descriptors of killed clients: {fds_before} -> {fds_after}");
    assert_eq!(entries_after, entries_before);
    assert_eq!(st.epoch, epoch);
    assert_eq!(st.state(), Some(bassport::State::Capturing));
    assert_eq!((st.xruns, st.gap_frames), (0, 0));
    assert_eq!(rf.u("corrupted"), 0);
    assert_eq!(rf.u("delivered") + rf.u("lost"), rf.u("requested"));
}
