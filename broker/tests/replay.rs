//! `sim:file:PATH.wav`: a recording made with `bass record` replayed through bassd and read
//! back through the port is bit-exact at the same frame indices; the sidecar's GAP chunks come
//! back as GAP chunks; a rate or channel mismatch is refused; `--loop` starts again.
//!
//! Brokers come from `Bassd::start_replaying` (bass-test-support): the one place that gives a
//! broker the right to open files from the test directory once a device policy exists.

use std::path::Path;

use bass_test_support::*;
use bassclient::format::{chunk_flags, error_code, State};
use bassclient::testsignal::pattern_sample;
use bassclient::Error;

fn wav_channels(path: &Path) -> Vec<Vec<i32>> {
    let mut r = hound::WavReader::open(path).unwrap();
    let n = r.spec().channels as usize;
    let mut ch = vec![Vec::new(); n];
    for (i, s) in r.samples::<i32>().enumerate() {
        ch[i % n].push(s.unwrap());
    }
    ch
}

/// Records `frames` frames of `device` from frame 1 into DIR/NAME.
fn record(b: &Bassd, device: &str, nfpc: u32, frames: u64, file: &str) -> std::path::PathBuf {
    b.client().acquire(&acquire_req(device, 8000, nfpc, 200, 2)).unwrap();
    let wav = b.dir.join(file);
    let o = bass(b, &["record", wav.to_str().unwrap(), "--from", "1", "--frames", &frames.to_string(), "-q"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    wav
}

#[test]
fn a_replayed_recording_is_bit_exact_at_the_same_frame_indices() {
    let dir = TempDir::new("replay");
    let b = Bassd::start_replaying(dir.path(), "default");
    let wav = record(&b, "sim:pattern", 80, 8000, "p.wav");
    let rec = wav_channels(&wav);
    let dev = format!("sim:file:{}", wav.display());
    let o = bass(&b, &["acquire", &dev, "-r", "8000", "--frames", "80", "--chunks", "200", "-c", "2"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let port = b.port();
    assert_eq!(port.epoch(), 2);
    wait_frame(&port, 8000);
    let got = read_frames(&port, 1, 8000);
    for c in 0..2 {
        for f in 0..8000usize {
            assert_eq!(got[c][f], rec[c][f], "frame {} channel {c}", f + 1);
            assert_eq!(got[c][f], pattern_sample(f as u64 + 1, c as u32));
        }
    }
    // The file ends: the acquisition ends as stopped (no error), with a message saying so,
    // and no frame more.
    match port.wait(8001, PATIENCE) {
        Err(Error::Stopped { .. }) => {
            let info = port.info().unwrap();
            assert_eq!(info.error_code, error_code::NONE);
            assert!(info.message.contains("end of the recording after 8000 frames"), "{}", info.message);
        }
        other => panic!("expected the end of the replay, got {other:?}"),
    }
    assert_eq!(port.info().unwrap().last_frame_index, 8000);
}

#[test]
fn the_gaps_of_a_recording_are_replayed_as_gaps() {
    // sim:xrun at 8000 Hz, 100-frame chunks: GAP chunks 4001..4400 and 8501..8800.
    let dir = TempDir::new("replay-gaps");
    let b = Bassd::start_replaying(dir.path(), "default");
    let wav = record(&b, "sim:xrun", 100, 9000, "x.wav");
    let rec = wav_channels(&wav);
    let dev = format!("sim:file:{}", wav.display());
    b.client().acquire(&acquire_req(&dev, 8000, 100, 200, 2)).unwrap();
    let port = b.port();
    wait_frame(&port, 9000);
    let got = read_frames(&port, 1, 9000);
    assert_eq!(got, rec, "every replayed sample equals the recorded one");
    let gaps: Vec<u64> = (0..90u64)
        .map(|k| port.chunk_info(100 * k + 1).unwrap())
        .filter(|ci| ci.flags & chunk_flags::GAP != 0)
        .map(|ci| ci.first_frame)
        .collect();
    assert_eq!(gaps, [4001, 4101, 4201, 4301, 8501, 8601, 8701]);
    let info = port.info().unwrap();
    assert_eq!((info.xruns, info.gap_frames), (2, 700));
}

#[test]
fn a_rate_or_channel_mismatch_is_refused_and_loop_starts_again() {
    let dir = TempDir::new("replay-args");
    let b = Bassd::start_replaying(dir.path(), "default");
    let wav = record(&b, "sim:pattern", 80, 800, "s.wav");
    let dev = format!("sim:file:{}", wav.display());
    let o = bass(&b, &["acquire", &dev, "-r", "48000", "-c", "2"]);
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    assert!(
        text(&o).contains("holds 8000 Hz, 2 channel(s)") && text(&o).contains("--rate 8000"),
        "{}",
        text(&o)
    );
    let o = bass(&b, &["acquire", &dev, "-r", "8000", "-c", "1"]);
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    // Outside the directory the operator allowed: refused by the device policy, nothing read.
    let o = bass(&b, &["acquire", "sim:file:/nonexistent/x.wav", "-r", "8000"]);
    assert_ne!(o.status.code(), Some(0), "{}", text(&o));
    assert!(text(&o).contains("device policy"), "{}", text(&o));
    let missing = format!("sim:file:{}/missing.wav", dir.path().display());
    let o = bass(&b, &["acquire", &missing, "-r", "8000"]);
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    assert!(text(&o).contains("cannot read the WAV file"), "{}", text(&o));
    // --loop: frame f replays frame ((f - 1) mod 800) + 1 of the recording.
    let o =
        bass(&b, &["acquire", &dev, "--loop", "-r", "8000", "--frames", "80", "--chunks", "200", "-c", "2"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let port = b.port();
    wait_frame(&port, 2400);
    let got = read_frames(&port, 1, 2400);
    for f in 1..=2400u64 {
        assert_eq!(got[1][f as usize - 1], pattern_sample((f - 1) % 800 + 1, 1), "frame {f}");
    }
    assert_eq!(port.info().unwrap().state, Some(State::Capturing));
}
