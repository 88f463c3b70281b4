//! `bass record` against a real bassd: sample-exact recordings of sim:pattern, gaps of
//! sim:xrun counted and marked, a recorder stopped by SIGTERM leaving a valid WAV (opened with
//! hound, sox and Python's wave module), a new acquisition ending the file; and the hostile
//! cases: a start the port no longer has, a full file system, SIGKILL, a recorder stopped for
//! longer than the window, symbolic links and existing files, a start far in the future, and
//! the plain PCM header every reader opens. Every recording is verified by
//! `bass record --check`.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

use bass_cli::record::convert;
use bass_test_support::*;
use basskit::testsignal::pattern_sample;
use bassport::format::chunk_flags;
use serde_json::Value;

/// The samples of a WAV file, per channel.
fn read_wav(path: &Path) -> (hound::WavSpec, Vec<Vec<i32>>) {
    let mut r = hound::WavReader::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let spec = r.spec();
    let mut ch = vec![Vec::new(); spec.channels as usize];
    for (i, s) in r.samples::<i32>().enumerate() {
        ch[i % spec.channels as usize].push(s.unwrap());
    }
    (spec, ch)
}

/// `bass record --check FILE` (no broker needed): asserts it passes, returns its line.
fn check_ok(wav: &Path) -> String {
    let o = Command::new(bass_bin()).args(["record", "--check"]).arg(wav).output().unwrap();
    assert_eq!(o.status.code(), Some(0), "bass record --check {}: {}", wav.display(), text(&o));
    let out = String::from_utf8_lossy(&o.stdout).trim().to_owned();
    assert!(out.starts_with("ok"), "{out}");
    out
}

fn sidecar(path: &Path) -> Value {
    let p = format!("{}.json", path.display());
    serde_json::from_slice(&std::fs::read(&p).unwrap_or_else(|e| panic!("{p}: {e}"))).unwrap()
}

#[test]
fn a_recording_of_the_pattern_is_exact_sample_by_sample_with_one_row_per_chunk() {
    let dir = TempDir::new("rec-pattern");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    let wav = dir.path().join("p.wav");
    let o = bass(&b, &["record", wav.to_str().unwrap(), "--from", "1", "--frames", "12000", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let summary: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((summary["frames"].as_u64(), summary["lost_frames"].as_u64()), (Some(12000), Some(0)));
    let (spec, ch) = read_wav(&wav);
    assert_eq!((spec.channels, spec.sample_rate, spec.bits_per_sample), (2, 8000, 32));
    for (c, samples) in ch.iter().enumerate() {
        assert_eq!(samples.len(), 12000);
        for (i, &s) in samples.iter().enumerate() {
            assert_eq!(s, pattern_sample(i as u64 + 1, c as u32), "frame {} channel {c}", i + 1);
        }
    }
    check_ok(&wav);
    let side = sidecar(&wav);
    assert_eq!(side["acquisition"]["device"], "sim:pattern");
    assert_eq!(side["acquisition"]["format"], "S32_LE");
    assert_eq!(side["acquisition"]["epoch"], 1);
    let rows = side["chunks"].as_array().unwrap();
    assert_eq!(rows.len(), 150);
    let mono0 = rows[0]["mono_ns"].as_u64().unwrap();
    for (k, r) in rows.iter().enumerate() {
        assert_eq!(r["first_frame"].as_u64(), Some(80 * k as u64 + 1));
        // LATE only says the simulated device caught up after the (shared, loaded) machine
        // delayed it; its frames and timestamps are still nominal. Nothing else may be set.
        let flags = r["flags"].as_u64().unwrap() as u32;
        assert_eq!(flags & !chunk_flags::LATE, 0, "chunk {k}: flags {flags}");
        assert_eq!(r["mono_ns"].as_u64().unwrap() - mono0, k as u64 * 10_000_000, "chunk {k}: 10 ms apart");
        assert!(r["realtime_ns"].as_u64().unwrap() > 0);
    }
    // 16 bits, one channel: rounded as documented.
    let wav16 = dir.path().join("p16.wav");
    let o = bass(
        &b,
        &[
            "record",
            wav16.to_str().unwrap(),
            "--from",
            "oldest",
            "-d",
            "0.5",
            "--bits",
            "16",
            "--channels",
            "1",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    check_ok(&wav16);
    let first = sidecar(&wav16)["recording"]["first_frame"].as_u64().unwrap();
    let (spec, ch) = read_wav(&wav16);
    assert_eq!((spec.channels, spec.bits_per_sample, ch[0].len()), (1, 16, 4000));
    for (i, &s) in ch[0].iter().enumerate() {
        assert_eq!(s, convert(pattern_sample(first + i as u64, 1), 16), "frame {}", first + i as u64);
    }
    // An existing file is kept unless --force.
    let o = bass(&b, &["record", wav16.to_str().unwrap(), "--frames", "80"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("--force"));
    let o = bass(&b, &["record", wav16.to_str().unwrap(), "--frames", "80", "--force", "-q"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
}

#[test]
fn gaps_of_an_overrun_are_counted_and_marked() {
    // sim:xrun at 8000 Hz zero-fills frames 4001..=4407 and 8408..=8814.
    let dir = TempDir::new("rec-xrun");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:xrun", 8000, 100, 200, 2)).unwrap();
    let wav = dir.path().join("x.wav");
    let o = bass(&b, &["record", wav.to_str().unwrap(), "--from", "1", "--frames", "9000", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let summary: Value = serde_json::from_slice(&o.stdout).unwrap();
    // Frames of GAP chunks (4001..4400, 8501..8800); the partly zero chunks are flagged
    // DISCONTINUITY in the sidecar.
    assert_eq!(summary["gap_frames"], 700, "{summary}");
    let (_, ch) = read_wav(&wav);
    let is_gap = |f: u64| (4001..=4407).contains(&f) || (8408..=8814).contains(&f);
    for f in 1..=9000u64 {
        for c in 0..2u32 {
            let want = if is_gap(f) { 0 } else { pattern_sample(f, c) };
            assert_eq!(ch[c as usize][f as usize - 1], want, "frame {f} channel {c}");
        }
    }
    check_ok(&wav);
    let side = sidecar(&wav);
    let rows = side["chunks"].as_array().unwrap();
    assert_eq!(rows.len(), 90);
    let with = |flag: u32| -> Vec<u64> {
        rows.iter()
            .filter(|r| r["flags"].as_u64().unwrap() as u32 & flag != 0)
            .map(|r| r["first_frame"].as_u64().unwrap())
            .collect()
    };
    assert_eq!(with(chunk_flags::GAP), [4001, 4101, 4201, 4301, 8501, 8601, 8701]);
    assert_eq!(with(chunk_flags::DISCONTINUITY), [4401, 8401, 8801]);
}

/// Starts `bass record ARGS`, waits until the WAV holds at least `bytes`, sends SIGTERM and
/// returns the exit code.
fn record_then_sigterm(b: &Bassd, wav: &Path, extra: &[&str], bytes: u64) -> i32 {
    let mut child = Command::new(bass_bin())
        .args(["--name", &b.name, "record", wav.to_str().unwrap()])
        .args(extra)
        .env("BASS_RUNTIME_DIR", &b.dir)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    eventually("the WAV to grow", || {
        (std::fs::metadata(wav).map(|m| m.len()).unwrap_or(0) >= bytes).then_some(())
    });
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let deadline = Instant::now() + PATIENCE;
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            return st.code().unwrap_or(-1);
        }
        assert!(Instant::now() < deadline, "the recorder did not stop on SIGTERM");
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

#[test]
fn a_recorder_stopped_by_sigterm_leaves_a_valid_finalised_wav() {
    let dir = TempDir::new("rec-term");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    for (file, extra) in [("t32.wav", &[][..]), ("t16.wav", &["--bits", "16"][..])] {
        let wav = dir.path().join(file);
        assert_eq!(record_then_sigterm(&b, &wav, extra, 20_000), 0, "{file}");
        check_ok(&wav);
        let side = sidecar(&wav);
        assert_eq!(side["recording"]["end"], "signal");
        assert_eq!(side["recording"]["in_progress"], false);
        let frames = side["recording"]["frames"].as_u64().unwrap();
        let first = side["recording"]["first_frame"].as_u64().unwrap();
        let (spec, ch) = read_wav(&wav);
        assert_eq!(ch[0].len() as u64, frames, "{file}: the header holds every frame written");
        for (i, &s) in ch[1].iter().enumerate() {
            assert_eq!(
                s,
                convert(pattern_sample(first + i as u64, 1), spec.bits_per_sample),
                "{file} frame {i}"
            );
        }
        let soxi = Command::new("soxi")
            .arg("-s")
            .arg(&wav)
            .output()
            .expect("soxi (scripts/install-deps.sh installs sox)");
        assert!(soxi.status.success(), "soxi {file}: {}", text(&soxi));
        assert_eq!(String::from_utf8_lossy(&soxi.stdout).trim(), frames.to_string(), "soxi {file}");
        let sox = Command::new("sox").arg(&wav).args(["-n", "stat"]).output().unwrap();
        assert!(sox.status.success(), "sox {file}: {}", text(&sox));
        if spec.bits_per_sample == 16 {
            // Python's wave module before 3.12 reads only plain PCM (16-bit, <= 2 channels);
            // 24/32-bit files are WAVE_FORMAT_EXTENSIBLE, as the format requires.
            let py = Command::new("python3")
                .args(["-c", "import sys, wave; w = wave.open(sys.argv[1]); print(w.getnframes(), w.getnchannels(), w.getsampwidth())"])
                .arg(&wav)
                .output()
                .unwrap();
            assert!(py.status.success(), "python wave: {}", text(&py));
            assert_eq!(String::from_utf8_lossy(&py.stdout).trim(), format!("{frames} 2 2"));
        }
    }
}

#[test]
fn a_new_acquisition_ends_the_file() {
    let dir = TempDir::new("rec-epoch");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    let wav = dir.path().join("e.wav");
    let child = Command::new(bass_bin())
        .args(["--name", "default", "record", wav.to_str().unwrap(), "--json", "-q"])
        .env("BASS_RUNTIME_DIR", dir.path())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    eventually("the WAV to grow", || {
        (std::fs::metadata(&wav).map(|m| m.len()).unwrap_or(0) > 8000).then_some(())
    });
    c.acquire(&acquire_req("sim:sine", 8000, 80, 200, 2)).unwrap();
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(0));
    let summary: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(summary["end"].as_str().unwrap().contains("new acquisition"), "{summary}");
    check_ok(&wav);
    let first = summary["first_frame"].as_u64().unwrap();
    let (_, ch) = read_wav(&wav);
    for (i, &s) in ch[0].iter().enumerate() {
        assert_eq!(s, pattern_sample(first + i as u64, 0), "only the first acquisition's frames");
    }
}

/// Every frame of `wav` is the pattern's frame `first + i`, except the recorder's losses,
/// which are zeros; returns the frames.
fn assert_pattern_except_losses(wav: &Path) -> u64 {
    let side = sidecar(wav);
    let first = side["recording"]["first_frame"].as_u64().unwrap();
    let losses: Vec<(u64, u64)> = side["losses"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| (l["first_frame"].as_u64().unwrap(), l["frames"].as_u64().unwrap()))
        .collect();
    let (spec, ch) = read_wav(wav);
    let channels: Vec<u32> = side["recording"]["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_u64().unwrap() as u32)
        .collect();
    for (k, &c) in channels.iter().enumerate() {
        for (i, &s) in ch[k].iter().enumerate() {
            let f = first + i as u64;
            let lost = losses.iter().any(|&(a, n)| (a..a + n).contains(&f));
            let want = if lost { 0 } else { convert(pattern_sample(f, c), spec.bits_per_sample) };
            assert_eq!(s, want, "{}: frame {f} channel {c} (lost: {lost})", wav.display());
        }
    }
    ch[0].len() as u64
}

#[test]
fn a_start_the_port_no_longer_has_is_reported_once_and_the_limit_counts_from_the_file_start() {
    // A window of 2000 frames (20 chunks of 100) that has moved past frame 4000.
    let dir = TempDir::new("rec-late");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 100, 20, 2)).unwrap();
    wait_frame(&b.port(), 4001);
    let wav = dir.path().join("late.wav");
    let o = bass(&b, &["record", wav.to_str().unwrap(), "--from", "1", "-d", "0.5", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("started"), "{}", text(&o));
    check_ok(&wav);
    let r = &sidecar(&wav)["recording"];
    let first = r["first_frame"].as_u64().unwrap();
    assert!(first > 4000 - 2000 && (first - 1) % 100 == 0, "the oldest chunk then on the port: {r}");
    assert_eq!(r["requested_first_frame"], 1, "{r}");
    assert_eq!(r["started_after_requested"].as_u64(), Some(first - 1), "{r}");
    assert_eq!((r["frames"].as_u64(), r["lost_frames"].as_u64()), (Some(4000), Some(0)), "{r}");
    assert_eq!(sidecar(&wav)["losses"].as_array().unwrap().len(), 0);
    assert_eq!(assert_pattern_except_losses(&wav), 4000);
}

#[test]
fn a_recorder_stopped_longer_than_the_window_loses_whole_chunks_inside_the_file() {
    let dir = TempDir::new("rec-stop");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 100, 20, 2)).unwrap();
    let port = b.port();
    let wav = dir.path().join("s.wav");
    let mut child = bass_cmd(&b, &["record", wav.to_str().unwrap(), "--frames", "24000", "-q"])
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    eventually("the WAV to grow", || {
        (std::fs::metadata(&wav).map(|m| m.len()).unwrap_or(0) >= 16_000).then_some(())
    });
    send_signal(child.id(), libc::SIGSTOP);
    // The port moves on by more than its window while the recorder is stopped.
    let at = port.info().unwrap().last_frame_index;
    wait_frame(&port, at + 2 * port.frames_on_port() + 100);
    send_signal(child.id(), libc::SIGCONT);
    assert_eq!(child.wait().unwrap().code(), Some(0));
    check_ok(&wav);
    let side = sidecar(&wav);
    let r = &side["recording"];
    let (first, frames) = (r["first_frame"].as_u64().unwrap(), r["frames"].as_u64().unwrap());
    assert_eq!(frames, 24000);
    let losses = side["losses"].as_array().unwrap();
    assert!(!losses.is_empty(), "the stop lost frames: {side}");
    for l in losses {
        let (lf, n) = (l["first_frame"].as_u64().unwrap(), l["frames"].as_u64().unwrap());
        assert_eq!((lf - 1) % 100, 0, "a loss starts at a chunk start: {l}");
        assert!(lf >= first && lf + n <= first + frames, "inside the file: {l}");
    }
    assert_eq!(assert_pattern_except_losses(&wav), 24000);
}

#[test]
fn a_full_file_system_ends_the_recording_with_a_consistent_wav_and_sidecar() {
    if skip(root_missing()) {
        return; // mounting the small file system needs root
    }
    let dir = TempDir::new("rec-full");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    let fs = Tmpfs::mount(&dir.path().join("small"), "256k");
    let wav = fs.path().join("full.wav");
    let o = bass(&b, &["record", wav.to_str().unwrap(), "--bits", "24", "-q"]);
    let msg = text(&o);
    assert_eq!(o.status.code(), Some(1), "{msg}");
    assert!(
        msg.contains(wav.to_str().unwrap()) && msg.contains("frames"),
        "names the file and the frames: {msg}"
    );
    check_ok(&wav);
    let r = &sidecar(&wav)["recording"];
    assert!(r["end"].as_str().unwrap().contains("No space left"), "{r}");
    assert_eq!(r["in_progress"], false);
    let frames = r["frames"].as_u64().unwrap();
    assert!(frames > 8000, "most of the 256 KiB hold frames: {r}");
    assert!(msg.contains(&format!("{frames} frames")), "the message gives the frames kept: {msg}");
    let len = std::fs::metadata(&wav).unwrap().len();
    assert_eq!(len, 68 + frames * 6, "whole frames only, nothing after the data");
    assert_eq!(assert_pattern_except_losses(&wav), frames);
    drop(fs);
}

#[test]
fn a_sigkilled_recorder_leaves_the_last_checkpoint_wav_and_sidecar() {
    let dir = TempDir::new("rec-kill");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    let wav = dir.path().join("k.wav");
    let mut child =
        bass_cmd(&b, &["record", wav.to_str().unwrap(), "-q"]).stdout(Stdio::null()).spawn().unwrap();
    let side = format!("{}.json", wav.display());
    eventually("a checkpoint with frames", || {
        let v: Value = serde_json::from_slice(&std::fs::read(&side).ok()?).ok()?;
        (v["recording"]["frames"].as_u64()? > 8000).then_some(())
    });
    send_signal(child.id(), libc::SIGKILL);
    child.wait().unwrap();
    check_ok(&wav);
    let r = &sidecar(&wav)["recording"];
    assert_eq!(r["in_progress"], true, "{r}");
    assert_eq!(assert_pattern_except_losses(&wav), r["frames"].as_u64().unwrap());
}

#[test]
fn symbolic_links_and_existing_files_are_refused() {
    let dir = TempDir::new("rec-link");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    let target = dir.path().join("target.wav");
    let link = dir.path().join("link.wav");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    for force in [&[][..], &["--force"][..]] {
        let o = bass(&b, &[&["record", link.to_str().unwrap(), "--frames", "80", "-q"][..], force].concat());
        assert_eq!(o.status.code(), Some(2), "{force:?}: {}", text(&o));
        assert!(text(&o).contains("symbolic link"), "{}", text(&o));
        assert!(!target.exists(), "{force:?}: the link's target was created");
    }
    // The sidecar too: a dangling link where FILE.wav.json goes.
    let wav = dir.path().join("a.wav");
    let side_target = dir.path().join("elsewhere.json");
    std::os::unix::fs::symlink(&side_target, dir.path().join("a.wav.json")).unwrap();
    for force in [&[][..], &["--force"][..]] {
        let o = bass(&b, &[&["record", wav.to_str().unwrap(), "--frames", "80", "-q"][..], force].concat());
        assert_eq!(o.status.code(), Some(2), "{}", text(&o));
        assert!(text(&o).contains("symbolic link"), "{}", text(&o));
        assert!(!side_target.exists() && !wav.exists(), "nothing created");
    }
    // An existing sidecar is kept unless --force.
    let wav = dir.path().join("b.wav");
    std::fs::write(dir.path().join("b.wav.json"), "mine").unwrap();
    let o = bass(&b, &["record", wav.to_str().unwrap(), "--frames", "80", "-q"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("--force"), "{}", text(&o));
    assert_eq!(std::fs::read_to_string(dir.path().join("b.wav.json")).unwrap(), "mine");
    assert!(!wav.exists());
}

#[test]
fn a_start_in_the_future_says_what_it_waits_for() {
    use std::io::{BufRead, BufReader};
    let dir = TempDir::new("rec-future");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    let port = b.port();
    let now = wait_frame(&port, 1);
    let target = now + 8000 * 1000;
    let wav = dir.path().join("f.wav");
    let mut child = bass_cmd(&b, &["record", wav.to_str().unwrap(), "--from", &target.to_string()])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let line = lines.next().expect("a line on stderr").unwrap();
    assert!(line.contains(&format!("waiting for frame {target}")), "{line}");
    assert!(line.contains("the port is at frame") && line.contains("s away"), "{line}");
    send_signal(child.id(), libc::SIGTERM);
    assert_eq!(child.wait().unwrap().code(), Some(0));
    check_ok(&wav);
    assert_eq!(sidecar(&wav)["recording"]["frames"], 0);
}

/// Python's `wave` module on `wav`: Ok("frames channels sampwidth") or Err(stderr).
fn python_wave(wav: &Path) -> Result<String, String> {
    let py = Command::new("python3")
        .args(["-c", "import sys, wave; w = wave.open(sys.argv[1]); print(w.getnframes(), w.getnchannels(), w.getsampwidth())"])
        .arg(wav)
        .output()
        .unwrap();
    if py.status.success() {
        Ok(String::from_utf8_lossy(&py.stdout).trim().to_owned())
    } else {
        Err(String::from_utf8_lossy(&py.stderr).into_owned())
    }
}

fn python_minor() -> u32 {
    let o = Command::new("python3").args(["-c", "import sys; print(sys.version_info[1])"]).output().unwrap();
    String::from_utf8_lossy(&o.stdout).trim().parse().unwrap()
}

#[test]
fn a_plain_pcm_header_opens_in_python_wave_and_sox_and_extensible_in_hound_and_sox() {
    let dir = TempDir::new("rec-pcm");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    for (file, extra, tag) in [
        ("pcm32.wav", &["--wav-format", "pcm"][..], 1u16),
        ("pcm24.wav", &["--wav-format", "pcm", "--bits", "24"][..], 1),
        ("ext32.wav", &[][..], 0xFFFE),
    ] {
        let wav = dir.path().join(file);
        let o = bass(&b, &[&["record", wav.to_str().unwrap(), "--frames", "800", "-q"][..], extra].concat());
        assert_eq!(o.status.code(), Some(0), "{}", text(&o));
        check_ok(&wav);
        let bytes = std::fs::read(&wav).unwrap();
        assert_eq!(u16::from_le_bytes([bytes[20], bytes[21]]), tag, "{file}: format tag");
        let (spec, _) = read_wav(&wav);
        let width = spec.bits_per_sample / 8;
        assert_eq!(assert_pattern_except_losses(&wav), 800, "{file} in hound");
        let soxi = Command::new("sox").arg("--i").arg("-s").arg(&wav).output().unwrap();
        assert_eq!(String::from_utf8_lossy(&soxi.stdout).trim(), "800", "sox --i {file}: {}", text(&soxi));
        let sox = Command::new("sox").arg(&wav).args(["-n", "stat"]).output().unwrap();
        assert!(sox.status.success(), "sox {file}: {}", text(&sox));
        let py = python_wave(&wav);
        if tag == 1 || python_minor() >= 12 {
            assert_eq!(py, Ok(format!("800 2 {width}")), "python wave {file}");
        } else {
            // Python <= 3.11 refuses WAVE_FORMAT_EXTENSIBLE (docs/broker.md says so).
            assert!(py.as_ref().is_err_and(|e| e.contains("unknown format: 65534")), "{py:?}");
        }
    }
}
