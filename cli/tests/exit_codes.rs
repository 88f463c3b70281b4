//! The exit-code table of `bass` (docs/broker.md, "Exit codes"; cli/src/exit.rs),
//! held against real processes: every documented code is produced by a real `bass` against a
//! real `bassd` (a real tmpfs for the full-port-directory case), and the documented table is
//! the one the code defines.

use std::process::{Command, Output};

use bass_cli::exit;
use bass_test_support::*;

fn code(o: &Output) -> i32 {
    o.status.code().unwrap_or_else(|| panic!("bass was killed: {}", text(o)))
}

#[test]
fn every_documented_exit_code_comes_from_its_case() {
    let dir = TempDir::new("exit-table");
    let mut b = Bassd::start(dir.path(), "table", &["--max-port-bytes", "1000000"], &[]);

    // 2: a usage error (clap), and a request the broker refuses as invalid.
    let o = bass(&b, &["acquire", "sim:sine", "--frames", "many"]);
    assert_eq!(code(&o), exit::USAGE, "{}", text(&o));
    let o = bass(&b, &["acquire", "sim:sine", "--frames", "4800", "--chunks", "1000"]);
    assert_eq!(code(&o), exit::USAGE, "over --max-port-bytes: {}", text(&o));
    assert!(text(&o).contains("[invalid-argument]") || text(&o).contains("max-port-bytes"), "{}", text(&o));

    // 2: a device the broker's policy does not allow (a file replay without an operator
    // pattern) is a refusal too.
    let o = bass(&b, &["acquire", "sim:file:/tmp/x.wav", "-r", "8000"]);
    assert_eq!(code(&o), exit::USAGE, "a device-policy refusal: {}", text(&o));
    assert!(text(&o).contains("device policy"), "{}", text(&o));

    // 3: no broker of that name.
    let o = Command::new(bass_bin())
        .args(["--name", "nobody-here", "status"])
        .env("BASS_RUNTIME_DIR", dir.path())
        .output()
        .unwrap();
    assert_eq!(code(&o), exit::NO_BROKER, "{}", text(&o));

    // 4: the device cannot be opened.
    let o = bass(&b, &["acquire", "hw:97,0"]);
    assert_eq!(code(&o), exit::DEVICE, "{}", text(&o));

    // 5: the acquisition being read ends on a device error.
    b.client().acquire(&acquire_req("sim:unplug", 8000, 100, 100, 2)).unwrap();
    let o = bass(&b, &["blocks", "--max-outage", "0.3"]);
    assert_eq!(code(&o), exit::DEVICE_ENDED, "{}", text(&o));

    // 6: the broker does not answer within --timeout.
    b.signal(libc::SIGSTOP);
    let o = bass(&b, &["--timeout", "0.5", "status"]);
    b.signal(libc::SIGCONT);
    assert_eq!(code(&o), exit::TIMEOUT, "{}", text(&o));

    // 0: success.
    let o = bass(&b, &["status"]);
    assert_eq!(code(&o), exit::OK, "{}", text(&o));
    b.signal(libc::SIGTERM);
    b.wait_exit();
}

/// An Acquire whose port does not fit in the port directory's file system is a refusal like
/// a window over `--max-port-bytes`: exit 2 (not 1, "internal"), with a message naming the
/// size needed and the space there is; the running acquisition is untouched.
#[test]
fn a_port_that_does_not_fit_in_the_port_directory_is_refused_with_exit_2_and_the_sizes() {
    if skip(root_missing()) {
        return;
    }
    let outer = TempDir::new("exit-full");
    let fs = Tmpfs::mount(&outer.join("shm"), "2m");
    let b = Bassd::start(fs.path(), "full", &[], &[]);
    // A small port fits (about 0.4 MiB) ...
    let a = b.client().acquire(&acquire_req("sim:sine", 48000, 480, 100, 2)).unwrap();
    wait_frame(&b.port(), 4800);
    // ... a 7 MiB one does not: 48000 frames x 20 chunks x 2 channels x 4 bytes (the current
    // port also stays until the switch).
    let o = bass(&b, &["acquire", "sim:sine", "--frames", "48000", "--chunks", "20"]);
    let t = text(&o);
    assert_eq!(code(&o), exit::USAGE, "a full port directory is a refusal: {t}");
    assert!(t.contains("needs") && t.contains("MiB") && t.contains("free"), "names the sizes: {t}");
    let s = b.client().status().unwrap();
    assert_eq!((s.epoch, s.state), (a.epoch, bassport::format::State::Capturing as u32), "{s:?}");
    drop(b);
}

/// The table in docs/broker.md is the one exit.rs defines: the same codes, and each
/// documented meaning on the constant of that value.
#[test]
fn the_documented_exit_code_table_is_the_one_the_code_uses() {
    let docs = include_str!("../../docs/broker.md");
    let section = docs.split("### Exit codes").nth(1).expect("docs/broker.md has an Exit codes section");
    let rows: Vec<(i32, String)> = section
        .lines()
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .filter_map(|l| {
            let mut cells = l.split('|').map(str::trim).filter(|c| !c.is_empty());
            let n = cells.next()?.parse().ok()?;
            Some((n, cells.next()?.to_lowercase()))
        })
        .collect();
    let src = include_str!("../src/exit.rs");
    let mut consts: Vec<i32> = src
        .lines()
        .filter_map(|l| l.trim().strip_prefix("pub const ")?.split_once(": i32 = "))
        .map(|(_, v)| v.trim_end_matches(';').parse().expect("an exit code literal"))
        .collect();
    consts.sort_unstable();
    let documented: Vec<i32> = rows.iter().map(|(n, _)| *n).collect();
    assert_eq!(documented, consts, "docs/broker.md's exit codes vs exit.rs's constants");
    let meaning = |n: i32| rows.iter().find(|(m, _)| *m == n).map(|(_, t)| t.as_str()).unwrap();
    for (value, words) in [
        (exit::OK, "success"),
        (exit::FAILURE, "any other failure"),
        (exit::USAGE, "usage error"),
        (exit::NO_BROKER, "broker cannot be reached"),
        (exit::DEVICE, "could not open or configure the device"),
        (exit::DEVICE_ENDED, "ended on a device error"),
        (exit::TIMEOUT, "timeout"),
    ] {
        assert!(meaning(value).contains(words), "docs row {value} ({}) should say {words:?}", meaning(value));
    }
    // The doc comment of exit.rs carries the same table, row for row.
    for (n, _) in &rows {
        assert!(src.contains(&format!("//! | {n} |")), "exit.rs's table lacks code {n}");
    }
}
