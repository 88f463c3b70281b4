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

/// Waits until the replay on `port` has ended; returns its message.
fn replay_end(port: &bassclient::Port) -> String {
    let deadline = std::time::Instant::now() + PATIENCE;
    loop {
        let info = port.info().unwrap();
        if info.state == Some(State::Stopped) {
            assert_eq!(info.error_code, error_code::NONE, "{}", info.message);
            return info.message;
        }
        assert!(std::time::Instant::now() < deadline, "the replay did not end: {info:?}");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

#[test]
fn a_recording_of_gap_chunks_only_replays_every_one_of_them_at_its_index() {
    // sim:xrun at 8000 Hz, 100-frame chunks: frames 4001..4400 are GAP chunks. Before the
    // fix the replay published nothing (last frame 0) yet said "after 400 frames".
    let dir = TempDir::new("replay-all-gap");
    let b = Bassd::start_replaying(dir.path(), "default");
    b.client().acquire(&acquire_req("sim:xrun", 8000, 100, 200, 2)).unwrap();
    let wav = b.dir.join("g.wav");
    let o = bass(&b, &["record", wav.to_str().unwrap(), "--from", "4001", "--frames", "400", "-q"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let dev = format!("sim:file:{}", wav.display());
    b.client().acquire(&acquire_req(&dev, 8000, 100, 200, 2)).unwrap();
    let port = b.port();
    let msg = replay_end(&port);
    assert!(
        msg.contains("end of the recording after 400 frames (frames 4001..=4400 at the recorded indices, 400 of them GAP"),
        "{msg}"
    );
    let info = port.info().unwrap();
    assert_eq!((info.last_frame_index, info.gap_frames), (4400, 400));
    for k in 0..4u64 {
        let ci = port.chunk_info(4001 + 100 * k).unwrap();
        assert_eq!(ci.flags & chunk_flags::GAP, chunk_flags::GAP, "chunk {}", ci.first_frame);
    }
    // Frames before the recording are lost, not zeros; then come its 400 GAP frames.
    let (mut out, mut nfr) = (vec![1; 8000], 1);
    let r = port.get_audio_data(8000, &mut nfr, &mut [&mut out[..]]).unwrap();
    assert_eq!((r.frames, r.loss, nfr), (400, 4000, 4401));
    assert!(out[..400].iter().all(|&s| s == 0));
}

#[test]
fn a_recording_ending_inside_a_chunk_is_completed_with_zeros_and_says_so() {
    let dir = TempDir::new("replay-partial");
    let b = Bassd::start_replaying(dir.path(), "default");
    let wav = record(&b, "sim:pattern", 100, 4850, "p.wav");
    let dev = format!("sim:file:{}", wav.display());
    b.client().acquire(&acquire_req(&dev, 8000, 100, 200, 2)).unwrap();
    let port = b.port();
    let msg = replay_end(&port);
    assert!(msg.contains("after 4850 frames (frames 1..=4850"), "{msg}");
    assert!(msg.contains("the last chunk is completed with 50 zero frames (to frame 4900)"), "{msg}");
    assert_eq!(port.info().unwrap().last_frame_index, 4900);
    let got = read_frames(&port, 4801, 4900);
    for f in 4801..=4900u64 {
        let want = if f <= 4850 { pattern_sample(f, 1) } else { 0 };
        assert_eq!(got[1][(f - 4801) as usize], want, "frame {f}");
    }
}

#[test]
fn another_chunk_size_or_a_sidecar_that_disagrees_is_refused_by_name() {
    let dir = TempDir::new("replay-refused");
    let b = Bassd::start_replaying(dir.path(), "default");
    let wav = record(&b, "sim:pattern", 100, 800, "s.wav");
    let dev = format!("sim:file:{}", wav.display());
    let o = bass(&b, &["acquire", &dev, "-r", "8000", "--frames", "80", "-c", "2"]);
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    assert!(
        text(&o).contains("was recorded with 100 frames per chunk") && text(&o).contains("use --frames 100"),
        "{}",
        text(&o)
    );
    // --renumber takes any chunk size: from frame 1.
    let o = bass(
        &b,
        &["acquire", &dev, "--renumber", "-r", "8000", "--frames", "80", "--chunks", "200", "-c", "2"],
    );
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let port = b.port();
    wait_frame(&port, 800);
    assert_eq!(read_frames(&port, 1, 800)[0][799], pattern_sample(800, 0));
    // A sidecar claiming a loss outside its file.
    let side = bassclient::sidecar::path_of(&wav);
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&side).unwrap()).unwrap();
    v["losses"] = serde_json::json!([{"first_frame": 700, "frames": 500}]);
    v["recording"]["lost_frames"] = serde_json::json!(500);
    std::fs::write(&side, serde_json::to_vec(&v).unwrap()).unwrap();
    let o = bass(&b, &["acquire", &dev, "-r", "8000", "--frames", "100", "-c", "2"]);
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    assert!(text(&o).contains("losses[0]: frames 700..=1199 are not inside the file"), "{}", text(&o));
}
