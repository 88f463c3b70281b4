//! The SIGBUS guard (`bassport::sigbus`): a port file shrunk under a reader's mapping is an
//! error of the call, not the death of the reader; any other SIGBUS still reaches whoever
//! handled it before (or kills the process, as without the guard).
//!
//! The cases that must end a process run in a child: this test binary started again with
//! `BASS_SIGBUS_CHILD` naming the case (the `child_*` tests are `#[ignore]`d and fail if run
//! any other way).

use bass_test_support::client as common;

use std::fs::OpenOptions;
use std::os::unix::process::ExitStatusExt;
use std::time::{Duration, Instant};

use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, Writer};

fn port_with_chunks(tag: &str) -> (std::path::PathBuf, Writer) {
    let path = common::temp_port_path(tag);
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 256, chunks_on_port: 16 };
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "sigbus".into(), group: None }).unwrap();
    for _ in 0..4 {
        w.publish(Source::Zeros, ChunkMeta::default()).unwrap();
    }
    (path, w)
}

#[test]
fn a_port_file_truncated_while_a_reader_sleeps_in_wait_is_an_error_of_the_wait() {
    // The reader waits for a frame that never comes; while it sleeps in futex(2) the file is
    // cut to 0 bytes. A wake-up reads the header without a size check (the guard makes it
    // safe): the wait must end with Corrupt well before its timeout, not with SIGBUS.
    let (path, w) = port_with_chunks("sigbus-wait");
    let port = Port::open_path(&path).unwrap();
    let lfi = w.last_frame_index();
    let timeout = Duration::from_secs(10);
    let (tid_tx, tid_rx) = std::sync::mpsc::channel();
    let waiter = std::thread::spawn(move || {
        tid_tx.send(common::thread_id()).expect("the test waits for the thread id");
        let started = Instant::now();
        let r = port.wait(lfi + 1_000_000, timeout);
        // Every later call on this handle is refused the same way.
        let mut nfr = 1;
        let (mut l, mut r2) = (vec![0; 64], vec![0; 64]);
        let again = port.get_audio_data(64, &mut nfr, &mut [&mut l, &mut r2]);
        (r, started.elapsed(), again, port.info().map(drop))
    });
    common::wait_blocked_in_futex(tid_rx.recv().expect("the waiter's thread id"));
    OpenOptions::new().write(true).open(&path).unwrap().set_len(0).unwrap();
    let (r, took, again, info) = waiter.join().unwrap();
    match r {
        Err(Error::Corrupt(m)) => assert!(m.contains("shrank"), "message: {m}"),
        other => panic!("wait on a port truncated during the sleep gave {other:?}, expected Corrupt"),
    }
    // Noticed at a wake-up (every liveness slice), not when the timeout ran out.
    assert!(took < timeout / 2, "the wait took {took:?}");
    assert!(matches!(again, Err(Error::Corrupt(_))), "a read afterwards gave {again:?}");
    assert!(matches!(info, Err(Error::Corrupt(_))), "info afterwards gave {info:?}");
    // The writer's own mapping is not guarded: leave it untouched (no Drop, which would
    // write its state into the vanished page).
    std::mem::forget(w);
    std::fs::remove_file(&path).unwrap();
}

/// Runs this test binary's `child_NAME` test in a child process; its exit status.
fn run_child(name: &str) -> std::process::ExitStatus {
    common::child_command(&format!("child_{name}"), "BASS_SIGBUS_CHILD", name).status().unwrap()
}

/// The start of child `name`: fails unless run by [`run_child`] for this very case.
fn child(name: &str) {
    assert_eq!(common::child_entry("BASS_SIGBUS_CHILD"), name, "started for another case");
}

/// Maps `len` bytes of a new file shared, shrinks the file to 0 and reads the first byte:
/// a SIGBUS that has nothing to do with any port.
fn touch_a_truncated_foreign_mapping() -> u8 {
    let path = common::temp_port_path("sigbus-foreign");
    let f = OpenOptions::new().read(true).write(true).create(true).truncate(true).open(&path).unwrap();
    f.set_len(8192).unwrap();
    // SAFETY: a fresh shared read-only mapping of an open file of 8192 bytes.
    let p = unsafe {
        libc::mmap(
            std::ptr::null_mut(),
            8192,
            libc::PROT_READ,
            libc::MAP_SHARED,
            std::os::fd::AsRawFd::as_raw_fd(&f),
            0,
        )
    };
    assert_ne!(p, libc::MAP_FAILED);
    f.set_len(0).unwrap();
    std::fs::remove_file(&path).unwrap();
    // SAFETY: `p` is a live mapping; the read raises SIGBUS (the page is past the end of the
    // file), which is the point of the test.
    unsafe { std::ptr::read_volatile(p as *const u8) }
}

#[test]
fn a_sigbus_outside_any_port_still_kills_the_process() {
    let status = run_child("foreign_default");
    assert_eq!(status.signal(), Some(libc::SIGBUS), "child ended with {status:?}, expected death by SIGBUS");
}

#[test]
#[ignore = "child process of a_sigbus_outside_any_port_still_kills_the_process, which runs it"]
fn child_foreign_default() {
    child("foreign_default");
    foreign_sigbus_with_a_port_open("sigbus-child-a");
}

/// Opens a port (which installs the guard), then raises a SIGBUS elsewhere; the process
/// must not survive it (exits 0 only if it did: the parent then fails).
fn foreign_sigbus_with_a_port_open(tag: &str) -> ! {
    let (path, w) = port_with_chunks(tag);
    let _port = Port::open_path(&path).unwrap();
    std::fs::remove_file(&path).unwrap();
    let v = touch_a_truncated_foreign_mapping();
    drop(w);
    println!("survived a foreign SIGBUS, read {v}");
    std::process::exit(0);
}

#[test]
fn a_sigbus_outside_any_port_reaches_the_handler_installed_before() {
    let status = run_child("foreign_chained");
    assert_eq!(
        status.code(),
        Some(42),
        "child ended with {status:?}, expected its own SIGBUS handler's exit 42"
    );
}

extern "C" fn exit_42(_sig: libc::c_int, _info: *mut libc::siginfo_t, _ctx: *mut std::ffi::c_void) {
    // SAFETY: _exit is async-signal-safe.
    unsafe { libc::_exit(42) }
}

#[test]
#[ignore = "child process of a_sigbus_outside_any_port_reaches_the_handler_installed_before, which runs it"]
fn child_foreign_chained() {
    child("foreign_chained");
    // The host's own SIGBUS handler, installed before bass is used.
    // SAFETY: a zeroed sigaction with a valid SA_SIGINFO handler; a valid out-pointer.
    unsafe {
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = exit_42 as *const () as usize;
        sa.sa_flags = libc::SA_SIGINFO;
        libc::sigemptyset(&mut sa.sa_mask);
        assert_eq!(libc::sigaction(libc::SIGBUS, &sa, std::ptr::null_mut()), 0);
    }
    foreign_sigbus_with_a_port_open("sigbus-child-b");
}

#[test]
fn the_guard_can_be_turned_off() {
    // BASS_SIGBUS_GUARD=0: no handler; a port truncated during a wait kills the reader, as
    // before the guard (hosts that must own SIGBUS themselves choose this).
    let status = common::child_command("child_guard_off", "BASS_SIGBUS_CHILD", "guard_off")
        .env("BASS_SIGBUS_GUARD", "0")
        .status()
        .unwrap();
    assert_eq!(status.signal(), Some(libc::SIGBUS), "child ended with {status:?}");
}

#[test]
#[ignore = "child process of the_guard_can_be_turned_off, which runs it"]
fn child_guard_off() {
    child("guard_off");
    let (path, w) = port_with_chunks("sigbus-child-c");
    let port = Port::open_path(&path).unwrap();
    OpenOptions::new().write(true).open(&path).unwrap().set_len(0).unwrap();
    std::fs::remove_file(&path).unwrap();
    // The first pass checks the size (Corrupt); the next wake-up would too without the guard,
    // so reach the unguarded access through the in-place view of a channel ring instead.
    let ring = port.channel_ring(0).unwrap();
    let mut out = [0i32; 4];
    ring.copy_to(0, &mut out);
    std::mem::forget(w);
    println!("survived, read {out:?}");
    std::process::exit(0);
}

#[test]
fn a_port_file_truncated_under_an_in_place_view_reads_zeros_and_the_view_is_reported_lost() {
    // Reading in place (`view` + `channel_ring`) touches the mapping outside any library
    // call's size check; a shrink there is caught by the guard: the copy reads zeros and
    // `view_overwritten` reports the whole view overwritten.
    let (path, w) = port_with_chunks("sigbus-view");
    let port = Port::open_path(&path).unwrap();
    let mut nfr = 1;
    let view = port.view(512, &mut nfr).unwrap();
    assert_eq!(view.frames, 512);
    assert_eq!(port.view_overwritten(&view), 0, "intact before the shrink");
    OpenOptions::new().write(true).open(&path).unwrap().set_len(4096).unwrap();
    let ring = port.channel_ring(0).unwrap();
    let mut out = vec![-1i32; view.segments[0].1];
    ring.copy_to(view.segments[0].0, &mut out);
    assert!(out.iter().all(|&s| s == 0), "the replaced mapping reads zeros");
    assert_eq!(port.view_overwritten(&view), 512, "a view over a shrunk file is all lost");
    assert!(matches!(port.chunk_info(1), Err(Error::Corrupt(_))));
    std::mem::forget(w);
    std::fs::remove_file(&path).unwrap();
}
