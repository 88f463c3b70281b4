//! `bass record` against a real bassd: sample-exact recordings of sim:pattern, gaps of
//! sim:xrun counted and marked, a recorder stopped by SIGTERM leaving a valid WAV (opened with
//! hound, sox and Python's wave module), a new acquisition ending the file.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

use bass_test_support::*;
use bassclient::format::chunk_flags;
use bassclient::testsignal::pattern_sample;
use bassd::cli::record::convert;
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
        let side = sidecar(&wav);
        assert_eq!(side["recording"]["end"], "signal");
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
    let first = summary["first_frame"].as_u64().unwrap();
    let (_, ch) = read_wav(&wav);
    for (i, &s) in ch[0].iter().enumerate() {
        assert_eq!(s, pattern_sample(first + i as u64, 0), "only the first acquisition's frames");
    }
}
