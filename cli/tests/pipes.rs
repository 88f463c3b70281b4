//! `bass` on a closed pipe, against a real bassd on sim:pattern: every command that writes to
//! stdout, piped into `head -1` and onto a pipe whose reader is already gone, ends quietly with
//! exit 0 (docs/broker.md, "Pipes"), never a panic (exit 101) or an error (exit 1).

use std::process::{Child, Command, Stdio};
use std::time::Instant;

use bass_test_support::*;

/// Waits for `child` (within [`PATIENCE`]) and returns its exit code and stderr.
fn finish(mut child: Child, what: &str) -> (Option<i32>, String) {
    let deadline = Instant::now() + PATIENCE;
    let st = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("{what}: bass did not end on its closed pipe");
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    (st.code(), err)
}

/// The line of `text` that says what happened (a panic's on EPIPE, if any).
fn first_line(text: &str) -> &str {
    let mut lines = text.lines();
    lines.clone().find(|l| l.contains("Broken pipe")).or(lines.next()).unwrap_or("")
}

/// The commands that write to stdout, with what their first line starts with (the last two
/// start a new acquisition and stop it).
fn commands(dir: &std::path::Path) -> Vec<(Vec<String>, &'static str)> {
    let wav = |n: &str| dir.join(n).display().to_string();
    let owned = |a: &[&str]| a.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    vec![
        (owned(&["blocks"]), "port default: epoch 1,"),
        (owned(&["blocks", "--json"]), "{\"event\":\"port\""),
        (owned(&["meter", "-i", "0.02"]), "ch0 "),
        (owned(&["meter", "--json", "-i", "0.02"]), "{\"epoch\":1,"),
        (owned(&["status"]), "broker      default"),
        (owned(&["status", "--json"]), "{\""),
        (owned(&["devices"]), "DEVICE "),
        (owned(&["devices", "--json"]), "{\""),
        (owned(&["completions", "bash"]), "_bass()"),
        (owned(&["record", &wav("head.wav"), "--frames", "800", "--json"]), "{\""),
        (owned(&["plot", "--live", "--seconds", "0.1", "-o", &wav("live.png")]), "wrote "),
        (owned(&["acquire", "sim:pattern", "-r", "8000", "--frames", "80", "--chunks", "50"]), "acquiring "),
        (owned(&["stop"]), "stopped"),
    ]
}

#[test]
fn every_command_piped_into_head_ends_quietly_with_exit_0() {
    let dir = TempDir::new("pipes-head");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 50, 2)).unwrap();
    wait_frame(&b.port(), 160);
    let mut problems = Vec::new();
    for (args, first) in commands(dir.path()) {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let mut bass = bass_cmd(&b, &args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
        let head = Command::new("head")
            .arg("-1")
            .stdin(Stdio::from(bass.stdout.take().unwrap()))
            .output()
            .expect("head");
        let got = String::from_utf8_lossy(&head.stdout).into_owned();
        if got.lines().count() != 1 || !got.starts_with(first) || !got.ends_with('\n') {
            problems.push(format!("{args:?}: head got {got:?}"));
        }
        let (code, err) = finish(bass, &format!("{args:?} | head -1"));
        if code != Some(0) || !err.is_empty() {
            problems.push(format!("{args:?} | head -1: exit {code:?}, stderr {:?}", first_line(&err)));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    // The recording itself is whole although nobody read its summary.
    let o = Command::new(bass_bin()).args(["record", "--check"]).arg(dir.join("head.wav")).output().unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
}

#[test]
fn every_command_on_a_pipe_nobody_reads_ends_quietly_with_exit_0() {
    let dir = TempDir::new("pipes-closed");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 50, 2)).unwrap();
    wait_frame(&b.port(), 160);
    let mut problems = Vec::new();
    for (args, _) in commands(dir.path()) {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let mut bass = bass_cmd(&b, &args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
        // The reading end closed before the first write: that write fails with EPIPE.
        drop(bass.stdout.take());
        let (code, err) = finish(bass, &format!("{args:?} on a closed pipe"));
        if code != Some(0) || !err.is_empty() {
            problems.push(format!("{args:?} on a closed pipe: exit {code:?}, stderr {:?}", first_line(&err)));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    // The recording itself is whole although nobody read its summary.
    let o = Command::new(bass_bin()).args(["record", "--check"]).arg(dir.join("head.wav")).output().unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
}
