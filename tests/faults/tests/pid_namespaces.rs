//! A broker and its readers in different pid namespaces: bassd in a container with readers on
//! the host, and a reader in a container with bassd on the host (`unshare --pid --fork`, as
//! root). A pid means nothing across the boundary: the header's `writer_pid` is bassd's pid in
//! its own namespace, and the peer of a control connection may have none in ours.
//!
//! Pass: control connections are served both ways; `writer_alive` is true while bassd runs and
//! a device stall is reported as the stall, not as a dead writer; once bassd is killed, every
//! wait ends with WRITER_GONE within `FOREIGN_WRITER_SILENCE` (+ two chunks) of its last
//! heartbeat. (Before the fix: the broker refused a client outside its namespace ("SO_PEERCRED:
//! Success") and the client refused a broker outside its own; bassd in a namespace stored pid 1
//! with the start time of the host's pid 1, so host readers never saw it die.)

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use bass_faults::figure;
use bass_test_support::{Bassd, TempDir, PATIENCE};
use bassport::format::{error_code, State};
use bassport::reader::FOREIGN_WRITER_SILENCE;
use bassport::{Error, Port};

const UNSHARE: [&str; 4] = ["unshare", "--pid", "--fork", "--kill-child"];
/// The child reader's environment variable (see `reader_in_a_namespace_child`).
const CHILD: &str = "BASS_T17_READER_DIR";

fn acquire(device: &str) -> Vec<&str> {
    vec!["--acquire", device, "--rate", "48000", "--frames", "480", "--chunks", "100", "--channels", "2"]
}

/// Whether this machine lets us make pid namespaces (util-linux's unshare). As root (CI) it
/// must: there a failure is the test's failure, not a skip.
fn can_unshare() -> bool {
    let out = Command::new(UNSHARE[0]).args(&UNSHARE[1..]).arg("true").output();
    let ok = out.as_ref().is_ok_and(|o| o.status.success());
    if !ok && rustix::process::geteuid().is_root() {
        panic!("as root, `unshare --pid --fork` failed: {out:?}");
    }
    ok
}

/// Waits for a frame far ahead: the port's end, whatever it is, and how long it took.
fn wait_far(port: &Port) -> (Error, Duration) {
    let t0 = Instant::now();
    let last = port.info().unwrap().last_frame_index;
    let e = port.wait(last + 100 * 48_000, PATIENCE).expect_err("no frame that far ahead is published");
    (e, t0.elapsed())
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_broker_in_its_own_pid_namespace_serves_host_clients_and_is_seen_to_die() {
    if !can_unshare() {
        figure!("17", "SKIPPED: `unshare --pid --fork` is not allowed here (needs root)");
        return;
    }
    let dir = TempDir::shm("pidns");
    // Capturing: alive to a host reader, then killed.
    let mut b = Bassd::builder(dir.path(), "ns").wrapper(&UNSHARE).args(&acquire("sim:pattern")).start();
    let port = b.port_once_acquired();
    port.wait(1, PATIENCE).expect("the first chunk");
    let info = port.info().unwrap();
    assert_eq!(info.writer_pid, 1, "bassd is pid 1 of its namespace");
    assert!(info.writer_alive, "a running broker in another pid namespace counts as alive");
    let st = b.client().status().expect("a client outside bassd's pid namespace is served");
    assert_eq!(st.state, State::Capturing as u32);
    port.wait(info.last_frame_index + 4800, PATIENCE).expect("frames go on");
    b.kill(libc::SIGKILL);
    let (e, took) = wait_far(&port);
    assert!(matches!(e, Error::WriterGone { pid: 1 }), "after SIGKILL: {e:?}");
    assert!(!port.info().unwrap().writer_alive);
    let bound = FOREIGN_WRITER_SILENCE + Duration::from_millis(20);
    assert!(took < PATIENCE, "took {took:?}");
    figure!(
        "17",
        "bassd in its own pid namespace (header pid 1), host reader: served, writer_alive; SIGKILL -> WRITER_GONE after {} ms (bound {} ms after the last heartbeat)",
        took.as_millis(),
        bound.as_millis()
    );

    // A stalled device: the broker lives on, so the stall is what readers are told.
    let b2 = Bassd::builder(dir.path(), "stall")
        .wrapper(&UNSHARE)
        .stall_ms(Some(3000))
        .args(&acquire("sim:stall"))
        .start();
    let port = b2.port_once_acquired();
    let (e, took) = wait_far(&port);
    match e {
        Error::Device { code, .. } => assert_eq!(code, error_code::DEVICE_STALLED),
        other => panic!("a stalled device in another pid namespace ended the wait with {other:?}"),
    }
    assert!(port.info().unwrap().writer_alive, "the broker is still running after the stall");
    figure!(
        "17",
        "sim:stall under --stall-ms 3000 in another pid namespace: the host reader's wait ended with DEVICE_STALLED after {} ms (silence > FOREIGN_WRITER_SILENCE of {} ms: the broker's heartbeat kept it alive)",
        took.as_millis(),
        FOREIGN_WRITER_SILENCE.as_millis()
    );
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_reader_in_its_own_pid_namespace_is_served_and_sees_the_broker_die() {
    if !can_unshare() {
        figure!("17", "SKIPPED: `unshare --pid --fork` is not allowed here (needs root)");
        return;
    }
    let dir = TempDir::shm("pidns-reader");
    let mut b = Bassd::builder(dir.path(), "host").args(&acquire("sim:pattern")).start();
    let port = b.port_once_acquired();
    port.wait(1, PATIENCE).unwrap();
    // This test binary again, as the reader below, in a pid namespace of its own.
    let exe = std::env::current_exe().unwrap();
    let mut child = Command::new(UNSHARE[0])
        .args(&UNSHARE[1..])
        .arg(&exe)
        .args(["--exact", "reader_in_a_namespace_child", "--ignored", "--nocapture", "--test-threads=1"])
        .env(CHILD, dir.path())
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn the reader");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines().map_while(Result::ok);
    // The line from `prefix` on (libtest prints its own text around it), or "" at EOF.
    let mut find = |prefix: &str| {
        lines.by_ref().find_map(|l| l.find(prefix).map(|at| l[at..].to_owned())).unwrap_or_default()
    };
    let line = find("READY");
    assert!(line.starts_with("READY"), "the reader did not get ready");
    let bassd_pid = b.pid();
    b.kill(libc::SIGKILL);
    let line = find("ENDED");
    let status = child.wait().unwrap();
    assert!(line.starts_with(&format!("ENDED gone pid={bassd_pid} ")), "{line:?}");
    assert!(status.success(), "the reader failed: {status}");
    figure!(
        "17",
        "reader in its own pid namespace, bassd on the host: served, writer_alive; SIGKILL -> {line}"
    );
}

/// The reader of the test above, run only as its child (inside `unshare`): prints READY once it
/// was served and sees the writer alive, then `ENDED gone pid=P ms=N` when its wait ends.
#[test]
#[ignore = "run by a_reader_in_its_own_pid_namespace_is_served_and_sees_the_broker_die"]
fn reader_in_a_namespace_child() {
    let Some(dir) = std::env::var_os(CHILD) else { return };
    assert_eq!(std::process::id(), 1, "not in a pid namespace of its own");
    let sock = std::path::Path::new(&dir).join("bass-host.sock");
    let mut c = bassport::control::Client::connect_path(&sock, "host")
        .expect("a broker outside this pid namespace is trusted (root or this user)");
    let st = c.status().expect("and answers");
    assert_eq!(st.state, State::Capturing as u32);
    let port = Port::open_path(&std::path::Path::new(&dir).join("bass-host.port")).unwrap();
    let info = port.info().unwrap();
    assert!(info.writer_alive, "the broker on the host counts as alive");
    port.wait(info.last_frame_index + 480, PATIENCE).expect("frames go on");
    println!("READY");
    let (e, took) = wait_far(&port);
    match e {
        Error::WriterGone { pid } => println!("ENDED gone pid={pid} ms={}", took.as_millis()),
        other => println!("ENDED {other:?}"),
    }
}
