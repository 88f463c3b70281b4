//! The `bass` command line against a real bassd: following restarts, exit codes, refused
//! arguments, gap frames per block, JSON output.
//!
//! `BASS_CLI=/path/to/bass` runs these tests against another build of the tool.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::Instant;

use bass_test_support::*;
use serde_json::Value;

/// A `bass` child whose stdout lines arrive on a channel.
struct Running {
    child: Child,
    lines: mpsc::Receiver<String>,
    seen: Vec<String>,
}

impl Running {
    fn spawn(b: &Bassd, args: &[&str]) -> Running {
        let mut child =
            bass_cmd(b, args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("spawn bass");
        let out = child.stdout.take().unwrap();
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(l).is_err() {
                    break;
                }
            }
        });
        Running { child, lines, seen: Vec::new() }
    }

    /// Waits for a line satisfying `f` (panics with everything seen if the child ends first).
    fn expect(&mut self, what: &str, f: impl Fn(&str) -> bool) -> String {
        let deadline = Instant::now() + PATIENCE;
        loop {
            match self.lines.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
                Ok(l) => {
                    self.seen.push(l.clone());
                    if f(&l) {
                        return l;
                    }
                }
                Err(_) => panic!("no line {what}; bass printed:\n{}", self.seen.join("\n")),
            }
        }
    }

    /// Waits for the exit; returns (exit code, all stdout lines, stderr).
    fn finish(mut self) -> (i32, Vec<String>, String) {
        let deadline = Instant::now() + PATIENCE;
        let st = loop {
            if let Some(st) = self.child.try_wait().unwrap() {
                break st;
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                panic!("bass did not exit; printed:\n{}", self.seen.join("\n"));
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        };
        self.seen.extend(self.lines.iter());
        let mut err = String::new();
        std::io::Read::read_to_string(self.child.stderr.as_mut().unwrap(), &mut err).unwrap();
        (st.code().unwrap_or(-1), self.seen, err)
    }
}

#[test]
fn blocks_follows_interrupting_acquires_and_ends_only_on_a_real_stop() {
    // Before the fix, `bass blocks` took the transient Stopped state of an interrupted
    // acquisition for the end in about 3 of 20 restarts.
    let dir = TempDir::new("follow");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 8000, 80, 50, 2)).unwrap();
    let mut r = Running::spawn(&b, &["blocks"]);
    r.expect("for epoch 1", |l| l.starts_with("port default: epoch 1,"));
    for epoch in 2..=25u64 {
        assert_eq!(c.acquire(&acquire_req("sim:pattern", 8000, 80, 50, 2)).unwrap().epoch, epoch);
        let want = format!("port default: epoch {epoch},");
        r.expect(&format!("for epoch {epoch}"), |l| l.starts_with(&want));
        r.expect(&format!("a block of epoch {epoch}"), |l| l.starts_with("block "));
    }
    c.stop().unwrap();
    let (code, lines, err) = r.finish();
    assert_eq!(code, 0, "{err}");
    assert!(lines.last().unwrap().starts_with("-- acquisition stopped at frame "), "{lines:?}");
    assert!(!lines.iter().any(|l| l.contains("acquisition ended")), "{lines:?}");
}

/// A device error is a pause `blocks` rides through (a replica's outage, a broker restarted
/// after its grace and a device that comes back all look like this): it says so and waits,
/// ending by its own limit (before issue 33: exit 5 at once); `--max-outage` bounds the wait.
#[test]
fn blocks_waits_through_a_device_error_and_exits_non_zero_past_max_outage() {
    let dir = TempDir::new("devfail");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:unplug", 8000, 100, 100, 2)).unwrap();
    let t0 = std::time::Instant::now();
    let o = bass(&b, &["blocks", "-d", "2"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(t0.elapsed() >= std::time::Duration::from_millis(1900), "ended by its limit, not the error");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.contains("-- the acquisition paused: device error") && out.contains("unplugged"),
        "{}",
        text(&o)
    );
    let o = bass(&b, &["blocks", "--max-outage", "0.5"]);
    assert_eq!(o.status.code(), Some(5), "{}", text(&o));
    assert!(text(&o).contains("device error") && text(&o).contains("--max-outage"), "{}", text(&o));
}

#[test]
fn blocks_shows_the_gap_frames_of_each_block() {
    // sim:xrun at 8000 Hz zero-fills frames 4001..=4407: chunks 4001..4400 are GAP chunks,
    // chunk 4401..4500 mixes zeros and data (a discontinuity). Before the fix every block
    // said `loss 0` and nothing else.
    let dir = TempDir::new("gaps");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:xrun", 8000, 100, 100, 2)).unwrap();
    let o = bass(&b, &["blocks", "--json", "--block", "100", "--count", "50", "--offset", "-100000"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let mut blocks = 0;
    for line in String::from_utf8_lossy(&o.stdout).lines() {
        let v: Value = serde_json::from_str(line).unwrap_or_else(|e| panic!("{line}: {e}"));
        if v["event"] != "block" {
            continue;
        }
        blocks += 1;
        let first = v["first_frame"].as_u64().unwrap();
        // The partly filled chunk's zero-filled frames count too (4401..=4407).
        let want = if (4001..=4301).contains(&first) {
            100
        } else if first == 4401 {
            7
        } else {
            0
        };
        assert_eq!(v["gap_frames"], want, "{line}");
        assert_eq!(v["loss"], 0, "{line}");
        if first == 4401 {
            assert_eq!(v["discontinuities"], 1, "{line}");
            assert_eq!(v["rms_dbfs"].as_array().unwrap().len(), 2);
        }
        assert_eq!(first, 100 * (blocks - 1) + 1, "blocks start at frame 1 and follow each other");
    }
    assert_eq!(blocks, 50);
    // The text form says it too.
    let o = bass(&b, &["blocks", "--block", "100", "--count", "45", "--offset", "-100000"]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.lines().any(|l| l.contains("frames       4001..4100") && l.contains("gap 100 ")), "{out}");
    assert!(out.lines().any(|l| l.contains("frames       4401..4500") && l.contains(" xrun")), "{out}");
}

/// The gap column counts every zero-filled frame the port counts in `gap_frames`: the frames
/// of GAP chunks and the zero-filled frames of a chunk that mixes data and zeros. Before the
/// fix it counted the GAP chunks only (400 of each overrun's 407 frames; `bass blocks` showed
/// "gap 2400" where the port counted 2541 after a restart).
#[test]
fn the_gap_column_adds_up_to_the_zero_filled_frames_the_port_counts() {
    // sim:xrun at 8000 Hz zero-fills frames 4001..=4407 and 8408..=8814 (2 x 407).
    let dir = TempDir::new("gap-sum");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:xrun", 8000, 100, 200, 2)).unwrap();
    let port = b.port();
    wait_frame(&port, 9000);
    let o = bass(&b, &["blocks", "--json", "--block", "100", "--count", "90", "--offset", "-100000"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let mut gaps = std::collections::BTreeMap::new();
    for line in String::from_utf8_lossy(&o.stdout).lines() {
        let v: Value = serde_json::from_str(line).unwrap();
        if v["event"] == "block" && v["gap_frames"].as_u64() != Some(0) {
            gaps.insert(v["first_frame"].as_u64().unwrap(), v["gap_frames"].as_u64().unwrap());
        }
    }
    let want = [(4001, 100), (4101, 100), (4201, 100), (4301, 100), (4401, 7)];
    let want: Vec<(u64, u64)> = want
        .iter()
        .chain(&[(8401, 93), (8501, 100), (8601, 100), (8701, 100), (8801, 14)])
        .copied()
        .collect();
    assert_eq!(gaps.into_iter().collect::<Vec<_>>(), want);
    // The port's own count of the same frames, once they are all published.
    let first_two: u64 = want.iter().map(|w| w.1).sum();
    assert_eq!(first_two, 814);
    let s = b.client().status().unwrap();
    assert!(s.gap_frames >= first_two, "the port counts {} zero-filled frames", s.gap_frames);
}

#[test]
fn bad_numbers_are_refused_with_the_option_and_range_never_a_panic() {
    // Before the fix: `--seconds inf`, `1e300`, `1e19` panicked (exit 101); NaN and negative
    // values meant "no limit"; a non-UTF-8 device name panicked.
    let dir = TempDir::new("ranges");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let cases: [(&[&str], &str); 11] = [
        (&["blocks", "--seconds", "inf"], "--seconds"),
        (&["blocks", "--seconds", "1e300"], "--seconds"),
        (&["blocks", "--seconds", "1e19"], "--seconds"),
        (&["blocks", "--seconds", "NaN"], "--seconds"),
        (&["blocks", "--seconds=-1"], "--seconds"),
        (&["blocks", "--block", "0"], "--block"),
        (&["acquire", "sim:sine", "--rate", "0"], "1..=768000"),
        (&["acquire", "sim:sine", "--channels", "65"], "1..=64"),
        (&["acquire", "sim:sine", "--frames=-5"], "--frames"),
        (&["acquire", "sim:sine", "--frames", "99999999999"], "--frames"),
        (&["--timeout", "0", "status"], "--timeout"),
    ];
    for (args, want) in cases {
        let o = bass(&b, args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o));
        assert!(text(&o).contains(want), "{args:?}: {}", text(&o));
    }
    use std::os::unix::ffi::OsStrExt;
    let o = bass_cmd(&b, &["acquire"]).arg(std::ffi::OsStr::from_bytes(b"sim:\xff\xfe")).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("invalid UTF-8"), "{}", text(&o));
    assert_eq!(b.client().status().unwrap().epoch, 0, "nothing was acquired");
}

#[test]
fn ignored_arguments_are_refused() {
    // Before the fix `bass acquire sim:sine 48000 480 100` ran at 44100/2205/20, and
    // `--format` on a sim: device was dropped silently.
    let dir = TempDir::new("ignored");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let o = bass(&b, &["acquire", "sim:sine", "48000", "480", "100"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("48000 is not a device name"), "{}", text(&o));
    let o = bass(&b, &["acquire", "sim:sine", "--format", "S16_LE"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("ALSA devices only"), "{}", text(&o));
    assert_eq!(b.client().status().unwrap().epoch, 0, "nothing was acquired");
    let o = bass(&b, &["acquire", "-D", "sim:sine", "-r", "8000", "-c", "1", "--frames", "80"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let s = b.client().status().unwrap();
    assert_eq!((s.sample_rate, s.channels, s.frames_per_chunk), (8000, 1, 80));
}

#[test]
fn exit_codes_tell_usage_broker_device_and_timeout_apart() {
    let dir = TempDir::new("exits");
    let mut b = Bassd::start(dir.path(), "default", &[], &[]);
    let code = |o: &Output| o.status.code();
    assert_eq!(code(&bass(&b, &["bogus"])), Some(2));
    let o = Command::new(bass_bin())
        .args(["--name", "nobody", "status"])
        .env("BASS_RUNTIME_DIR", &b.dir)
        .output()
        .unwrap();
    assert_eq!(code(&o), Some(3), "{}", text(&o));
    assert!(text(&o).contains("is bassd --name nobody running"), "{}", text(&o));
    // No port within --timeout: the "waiting" notice, then exit 6.
    let o = bass(&b, &["--timeout", "1.5", "blocks"]);
    assert_eq!(code(&o), Some(6), "{}", text(&o));
    assert!(text(&o).contains("waiting for the port default"), "{}", text(&o));
    assert!(text(&o).contains("bass --name default acquire DEVICE"), "{}", text(&o));
    let o = bass(&b, &["acquire", "hw:97,0"]);
    assert_eq!(code(&o), Some(4), "{}", text(&o));
    assert!(
        text(&o).contains("bass --name default devices") && text(&o).contains("sim:sine"),
        "{}",
        text(&o)
    );
    let o = bass(&b, &["acquire", "sim:pattern", "--frames", "4000000", "--chunks", "4000"]);
    assert_eq!(code(&o), Some(2), "a request the broker refuses: {}", text(&o));
    // A stopped broker: the reply never comes; --timeout bounds the wait.
    b.signal(libc::SIGSTOP);
    let o = bass(&b, &["--timeout", "0.5", "status"]);
    b.signal(libc::SIGCONT);
    assert_eq!(code(&o), Some(6), "{}", text(&o));
    assert!(text(&o).contains("raise --timeout"), "{}", text(&o));
    b.signal(libc::SIGTERM);
    b.wait_exit();
}

#[test]
fn json_output_parses_with_the_c_field_names() {
    let dir = TempDir::new("json");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let o = bass(&b, &["devices", "--json"]);
    let devs: Vec<Value> =
        String::from_utf8_lossy(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert!(devs.iter().any(|d| d["name"] == "sim:pattern" && d["description"].is_string()), "{devs:?}");
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 50, 2)).unwrap();
    let port = b.port();
    wait_frame(&port, 160);
    let o = bass(&b, &["status", "--json"]);
    let s: Value = serde_json::from_slice(&o.stdout).unwrap();
    for k in ["state", "error_code", "sample_rate", "frames_per_chunk", "chunks_on_port", "channels", "epoch"]
    {
        assert!(s[k].is_u64(), "{k} in {s}");
    }
    assert_eq!((s["state_name"].as_str(), s["sample_rate"].as_u64()), (Some("capturing"), Some(8000)));
    assert!(s["last_frame_index"].as_u64().unwrap() >= 160);
    let o = bass(&b, &["blocks", "--json", "--count", "2"]);
    let lines: Vec<Value> =
        String::from_utf8_lossy(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 4, "port, 2 blocks, end: {lines:?}");
    assert_eq!((lines[0]["event"].as_str(), lines[0]["channels"].as_u64()), (Some("port"), Some(2)));
    assert_eq!((lines[1]["event"].as_str(), lines[1]["frames"].as_u64()), (Some("block"), Some(80)));
    assert_eq!(lines[3]["event"], "end");
}

#[test]
fn completions_and_version() {
    for shell in ["bash", "zsh", "fish"] {
        let o = Command::new(bass_bin()).args(["completions", shell]).output().unwrap();
        assert!(o.status.success());
        assert!(String::from_utf8_lossy(&o.stdout).contains("blocks"), "{shell}");
    }
    for bin in [bass_bin(), bassd_bin().to_owned()] {
        let o = Command::new(&bin).arg("-V").output().unwrap();
        assert!(o.status.success() && String::from_utf8_lossy(&o.stdout).contains(env!("CARGO_PKG_VERSION")));
    }
}

#[test]
fn a_second_stop_says_already_stopped() {
    // Before the fix `bass stop` printed "stopped" whatever the broker had done.
    let dir = TempDir::new("stop-twice");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let o = bass(&b, &["stop"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(text(&o).contains("nothing to stop"), "{}", text(&o));
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 50, 2)).unwrap();
    wait_frame(&b.port(), 80);
    let first = bass(&b, &["stop"]);
    let first = String::from_utf8_lossy(&first.stdout).into_owned();
    assert!(first.starts_with("stopped at frame "), "{first}");
    let second = bass(&b, &["stop"]);
    assert_eq!(second.status.code(), Some(0), "{}", text(&second));
    let second = String::from_utf8_lossy(&second.stdout).into_owned();
    let frame = first.trim().trim_start_matches("stopped at frame ");
    assert_eq!(second.trim(), format!("already stopped at frame {frame}"));
}

#[test]
fn follower_channels_give_each_follower_its_own_count() {
    let dir = TempDir::new("follower-ch");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let master = ["acquire", "sim:field", "sim:field?ppm=87", "-r", "48000", "--frames", "480", "-c", "2"];
    // A count per follower, checked before anything is asked of the broker.
    for (extra, says) in [
        (&["--follower-channels", "4,2"][..], "--follower-channels has 2 count(s) for 1 follower device(s)"),
        (&["--follower-channels", "0"][..], "0 is out of range (1..=64 channels)"),
        (&["--follower-channels", "four"][..], "\"four\" is not a channel count"),
    ] {
        let o = bass(&b, &[&master[..], extra].concat());
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {}", text(&o));
        assert!(text(&o).contains(says), "{extra:?}: {}", text(&o));
    }
    assert_eq!(b.client().status().unwrap().devices.len(), 0, "nothing was acquired");
    let o = bass(&b, &[&master[..], &["--follower-channels", "4"]].concat());
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let port = b.port();
    assert_eq!(port.geometry().channels, 6, "master 2 + follower 4");
    wait_frame(&port, 4800);
    let o = bass(&b, &["status", "--json"]);
    let s: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(s["channels"].as_u64(), Some(6), "{s}");
    let rows: Vec<(String, u64, u64)> = s["devices"]
        .as_array()
        .unwrap_or_else(|| panic!("no devices in {s}"))
        .iter()
        .map(|d| {
            (
                d["role"].as_str().unwrap().to_owned(),
                d["first_channel"].as_u64().unwrap(),
                d["channels"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(rows, [("master".into(), 0, 2), ("follower".into(), 2, 4)]);
    // The follower's four channels carry its samples (the field's channels 0..3), once aligned
    // frames come: not all zero.
    let last = wait_frame(&port, 48_000);
    let data = read_frames(&port, last - 4799, last);
    for (c, samples) in data.iter().enumerate().skip(2) {
        assert!(samples.iter().any(|&v| v != 0), "follower channel {c} is silent");
    }
    let o = bass(&b, &["status"]);
    assert!(text(&o).contains("sim:field?ppm=87"), "{}", text(&o));
}
