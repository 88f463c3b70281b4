//! The blocking wait ends with the right outcome for each way an acquisition can go on or
//! end: a publish, a timeout, a stop, a device error, a new acquisition, a dead writer.
//! Waits use generous timeouts only as a guard; the assertions are on the outcomes.

use bass_test_support::client as common;

use std::process::Stdio;
use std::time::Duration;

use bassport::format::error_code;
use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, State, Writer};

const GUARD: Duration = Duration::from_secs(20);

fn params() -> PortParams {
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 32, chunks_on_port: 4 };
    PortParams { geometry, device: "wait-test".into(), group: None }
}

/// Runs `act` on the writer in another thread once the reader sleeps in its wait (futex(2)).
fn wait_while(
    writer: Writer,
    frame: u64,
    act: impl FnOnce(&mut Writer) + Send + 'static,
) -> (Result<u64, Error>, Writer) {
    let port = Port::open_path(writer.path()).unwrap();
    let reader = common::thread_id();
    let t = std::thread::spawn(move || {
        let mut w = writer;
        common::wait_blocked_in_futex(reader);
        act(&mut w);
        w
    });
    let r = port.wait(frame, GUARD);
    (r, t.join().unwrap())
}

#[test]
fn a_publish_wakes_the_waiter_with_the_new_last_frame() {
    let w = Writer::create_at(&common::temp_port_path("wake"), &params()).unwrap();
    let (r, w) = wait_while(w, 32, |w| {
        w.publish(Source::Zeros, ChunkMeta::default()).unwrap();
    });
    assert_eq!(r.unwrap(), 32);
    w.remove().unwrap();
}

#[test]
fn an_unpublished_frame_times_out_with_the_last_frame() {
    let mut w = Writer::create_at(&common::temp_port_path("timeout"), &params()).unwrap();
    w.publish(Source::Zeros, ChunkMeta::default()).unwrap();
    let port = Port::open_path(w.path()).unwrap();
    match port.wait(33, Duration::from_millis(30)) {
        Err(Error::Timeout { frame: 33, last: 32 }) => {}
        other => panic!("expected a timeout at frame 33, last 32: {other:?}"),
    }
    w.remove().unwrap();
}

#[test]
fn a_stop_ends_the_wait_as_stopped() {
    let w = Writer::create_at(&common::temp_port_path("stop"), &params()).unwrap();
    let (r, w) = wait_while(w, 1, |w| w.stop());
    assert!(matches!(r, Err(Error::Stopped { last: 0 })), "{r:?}");
    w.remove().unwrap();
}

#[test]
fn a_device_error_ends_the_wait_with_code_and_message() {
    let w = Writer::create_at(&common::temp_port_path("err"), &params()).unwrap();
    let (r, w) = wait_while(w, 1, |w| {
        w.set_state(State::Error, error_code::DEVICE_STALLED, "device stalled: no data for 200 ms")
    });
    match r {
        Err(Error::Device { code, message }) => {
            assert_eq!(code, error_code::DEVICE_STALLED);
            assert_eq!(message, "device stalled: no data for 200 ms");
        }
        other => panic!("expected a device error: {other:?}"),
    }
    w.remove().unwrap();
}

#[test]
fn a_new_acquisition_ends_the_wait_as_restarted_with_the_next_epoch() {
    let path = common::temp_port_path("restart");
    let w = Writer::create_at(&path, &params()).unwrap();
    assert_eq!(w.epoch(), 1);
    let p2 = path.clone();
    let (r, w) = wait_while(w, 1, move |_| {
        // The same process creates the next acquisition's port (as the broker does).
        let next = Writer::create_at(&p2, &params()).unwrap();
        assert_eq!(next.epoch(), 2);
        std::mem::forget(next); // keep it capturing; removed below
    });
    assert!(matches!(r, Err(Error::Restarted)), "{r:?}");
    let reopened = Port::open_path(&path).unwrap();
    assert_eq!(reopened.epoch(), 2);
    drop(w);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn a_killed_writer_process_ends_the_wait_as_writer_gone() {
    let path = common::temp_port_path("killed");
    let mut child = common::child_command("writer_child_entry", "BASS_WAIT_CHILD_PORT", &path)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    while !line.contains("ready") {
        line.clear();
        assert!(std::io::BufRead::read_line(&mut out, &mut line).unwrap() > 0, "child exited early");
    }
    let port = Port::open_path(&path).unwrap();
    let pid = child.id();
    let reader = common::thread_id();
    let killer = std::thread::spawn(move || {
        common::wait_blocked_in_futex(reader);
        // SAFETY: signalling our own child.
        unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) };
    });
    // The child is not reaped until after the wait: a zombie must count as gone too.
    let r = port.wait(u64::MAX / 4, GUARD);
    killer.join().unwrap();
    assert!(matches!(r, Err(Error::WriterGone { pid: p }) if p == pid), "{r:?}");
    child.wait().unwrap();
    std::fs::remove_file(&path).unwrap();
}

/// Child process for the test above: creates a port, publishes one chunk, then stays alive
/// (the sleep is the condition: a live writer) until it is killed.
#[test]
#[ignore = "child process of a_killed_writer_process_ends_the_wait_as_writer_gone, which runs it"]
fn writer_child_entry() {
    let path = common::child_entry("BASS_WAIT_CHILD_PORT");
    let mut w = Writer::create_at(std::path::Path::new(&path), &params()).unwrap();
    w.publish(Source::Zeros, ChunkMeta::default()).unwrap();
    println!("ready");
    std::thread::sleep(Duration::from_secs(60));
}
