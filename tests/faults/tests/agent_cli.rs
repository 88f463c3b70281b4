//! The fault agent's own contract: its command line (clap) refuses a bad value with a clear
//! error, and an agent whose test has stopped reading its stdout ends quietly (status 0, no
//! panic) instead of dying on "failed printing to stdout: Broken pipe" — the panic CI saw in
//! `pin-loop` when port_lifecycle's member test read one line and let go.

use std::os::fd::OwnedFd;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::Duration;

use bass_faults::agent_path;
use bass_test_support::{wait_until, Bassd, TempDir};

/// A stdout for a child whose reader has already hung up: the write end of a pipe whose read
/// end is closed, so the child's first write fails with EPIPE (Rust ignores SIGPIPE).
fn hung_up_stdout() -> Stdio {
    let (read, write): (OwnedFd, OwnedFd) = rustix::pipe::pipe().expect("pipe");
    drop(read);
    Stdio::from(write)
}

/// Runs the agent with `args`, stdin at EOF and a hung-up stdout; returns its status and
/// stderr once it has ended.
fn run_hung_up(args: &[&str]) -> (ExitStatus, String) {
    let child = Command::new(agent_path())
        .args(args)
        .stdin(Stdio::null())
        .stdout(hung_up_stdout())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn the agent");
    finish(child)
}

/// Waits (bounded) for `child` to exit, killing it if it does not; returns its status and
/// what it wrote on stderr.
fn finish(mut child: Child) -> (ExitStatus, String) {
    let exited = wait_until(Duration::from_secs(30), || child.try_wait().ok().flatten().is_some());
    if !exited {
        let _ = child.kill();
    }
    let out = child.wait_with_output().expect("wait for the agent");
    assert!(exited, "the agent did not end within 30 s; stderr: {}", String::from_utf8_lossy(&out.stderr));
    (out.status, String::from_utf8_lossy(&out.stderr).into_owned())
}

fn assert_quiet_end(role: &str, status: ExitStatus, stderr: &str) {
    assert!(
        status.success() && !stderr.contains("panicked") && !stderr.contains("Broken pipe"),
        "{role} with a hung-up stdout: {status}; stderr: {stderr}"
    );
}

#[test]
fn a_writer_whose_test_stopped_reading_ends_quietly() {
    let dir = TempDir::shm("agent-epipe");
    let port = dir.join("bass-epipe.port");
    let (status, stderr) = run_hung_up(&["writer", "--port", port.to_str().unwrap(), "--chunks", "4"]);
    assert_quiet_end("writer", status, &stderr);
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh (needs bassd built)"]
fn a_pin_loop_whose_test_stopped_reading_ends_quietly() {
    let dir = TempDir::shm("agent-pin-epipe");
    let b = Bassd::start_stock(dir.path(), "pe", &[], &[]);
    let socket = b.socket();
    let (status, stderr) = run_hung_up(&[
        "pin-loop",
        "--socket",
        socket.to_str().unwrap(),
        "--name",
        "pe",
        "--rate",
        "8000",
        "--nfpc",
        "80",
        "--ncop",
        "4",
        "--rounds",
        "2",
    ]);
    assert_quiet_end("pin-loop", status, &stderr);
    // The agent did reach the broker: its Acquire went through before it tried to report it.
    let s = b.client().status().expect("status");
    assert!(s.epoch >= 1, "pin-loop never acquired (epoch {})", s.epoch);
}

#[test]
fn a_bad_value_is_refused_with_the_option_named_and_status_2() {
    for (args, needle) in [
        (&["reader", "--port", "/nonexistent", "--mode", "bogus"][..], "invalid value 'bogus' for '--mode"),
        (&["writer", "--port", "/nonexistent", "--nfpc", "64k"][..], "invalid value '64k' for '--nfpc"),
        (&["follow", "--port", "/nonexistent", "--expect", "noise"][..], "possible values: zero, pattern"),
        (&["writer", "--port", "/nonexistent", "--pace-us", "3600000001"][..], "not in 0..=3600000000"),
        (&["pin-loop", "--name", "x"][..], "--socket <SOCKET>"),
        (&["no-such-role"][..], "unrecognized subcommand 'no-such-role'"),
    ] {
        let out = Command::new(agent_path()).args(args).stdin(Stdio::null()).output().expect("run the agent");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}; stderr: {err}", out.status);
        assert!(err.contains(needle), "{args:?}: stderr lacks {needle:?}: {err}");
    }
}
