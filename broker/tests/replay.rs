//! `sim:file:PATH.wav`: a recording made with `bass record` replayed through bassd and read
//! back through the port is bit-exact at the same frame indices; the sidecar's GAP chunks come
//! back as GAP chunks; a rate or channel mismatch is refused; `--loop` starts again.
//!
//! Brokers come from `Bassd::start_replaying` (bass-test-support): the one place that gives a
//! broker the right to open files from the test directory once a device policy exists.

use std::path::Path;

use bass_test_support::*;
use basskit::testsignal::pattern_sample;
use bassport::format::{chunk_flags, error_code, State};
use bassport::Error;

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

/// A relative `sim:file:` name means nothing to bassd, whose working directory is not the
/// client's: the broker refuses it by what it is (not as a device-policy matter, which is what
/// docs/broker.md's own `sim:file:rec` example met), and `bass acquire` makes the name
/// absolute against its own working directory first, so that example replays.
#[test]
fn a_relative_replay_path_is_refused_as_relative_and_bass_acquire_resolves_it() {
    let dir = TempDir::new("replay-relative");
    let b = Bassd::start_replaying(dir.path(), "default");
    let wav = record(&b, "sim:pattern", 80, 800, "rel.wav");
    for dev in ["sim:file:rel.wav", "sim:file-loop:./rel.wav", "sim:file-renumber:rec/../rel.wav"] {
        let e = b.client().acquire(&acquire_req(dev, 8000, 80, 200, 2)).unwrap_err().to_string();
        assert!(
            e.contains("relative path")
                && e.contains("give an absolute path")
                && e.ends_with("[invalid-argument]"),
            "{dev}: {e}"
        );
    }
    assert_eq!(b.client().status().unwrap().epoch, 1, "a refusal changes nothing");
    let o = bass_cmd(&b, &["acquire", "sim:file:rel.wav", "-r", "8000", "--frames", "80", "--chunks", "200"])
        .current_dir(dir.path())
        .output()
        .expect("run bass");
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let s = b.client().status().unwrap();
    assert_eq!((s.epoch, s.device), (2, format!("sim:file:{}", wav.display())));
    let port = b.port();
    wait_frame(&port, 800);
    let got = read_frames(&port, 1, 800);
    for f in 1..=800u64 {
        assert_eq!(got[0][f as usize - 1], pattern_sample(f, 0), "frame {f}");
    }
}

/// Waits until the replay on `port` has ended; returns its message.
fn replay_end(port: &bassport::Port) -> String {
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
    let side = basskit::sidecar::path_of(&wav);
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&side).unwrap()).unwrap();
    v["losses"] = serde_json::json!([{"first_frame": 700, "frames": 500}]);
    v["recording"]["lost_frames"] = serde_json::json!(500);
    std::fs::write(&side, serde_json::to_vec(&v).unwrap()).unwrap();
    let o = bass(&b, &["acquire", &dev, "-r", "8000", "--frames", "100", "-c", "2"]);
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    assert!(text(&o).contains("losses[0]: frames 700..=1199 are not inside the file"), "{}", text(&o));
}

/// An MCAP recording as `bass record --format mcap` writes it, built here: 1 channel at
/// 8000 Hz, 100-frame chunks, the audio `runs` (first frame, chunks, frames lost before it;
/// sample = frame index) and `frames` frames in all from frame 1 (the rest lost at the end).
fn mcap_recording(dir: &Path, name: &str, runs: &[(u64, u64, u64)], frames: u64) -> std::path::PathBuf {
    mcap_recording_as(dir, name, runs, frames, false)
}

/// The bound and masks [`mcap_recording_as`] gives the chunk at frame `f` (chunk k from 0):
/// bound 1000·k + 7, unknown for every third; channel 0 missing in odd chunks and unaligned
/// in chunks 2, 3, 6, 7, ...
fn mcap_ext(f: u64) -> (u64, u64, u64) {
    let k = (f - 1) / 100;
    let bound = if k % 3 == 2 { bassport::format::BOUND_UNKNOWN } else { 1000 * k + 7 };
    (bound, k & 1, (k >> 1) & 1)
}

/// [`mcap_recording`]; with `old`, its ChunkInfo messages and schema as bass wrote them before
/// port format 2.4 (the message ends at `lost_before`).
fn mcap_recording_as(
    dir: &Path,
    name: &str,
    runs: &[(u64, u64, u64)],
    frames: u64,
    old: bool,
) -> std::path::PathBuf {
    use basskit::ros2::{self, AudioDataStamped, ChunkInfo, Header, Time};
    use basskit::sidecar::{Acquisition, Lost, Recording, Sidecar};
    use std::collections::BTreeMap;
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(None)
        .create(std::io::Cursor::new(Vec::new()))
        .unwrap();
    let meta = BTreeMap::new();
    let new_fields = ["uint64 bound_ns", "uint64 missing_channels", "uint64 unaligned_channels"];
    let info_def: String = ros2::CHUNK_INFO_DEFINITION
        .lines()
        .filter(|l| !old || !new_fields.iter().any(|f| l.starts_with(f)))
        .map(|l| format!("{l}\n"))
        .collect();
    let s1 = w.add_schema(ros2::CHUNK_INFO, "ros2msg", info_def.as_bytes()).unwrap();
    let c1 = w.add_channel(s1, "/bass/t/chunk_info", "cdr", &meta).unwrap();
    let def = ros2::AUDIO_DATA_STAMPED_DEFINITION.as_bytes();
    let s2 = w.add_schema(ros2::AUDIO_DATA_STAMPED, "ros2msg", def).unwrap();
    let c2 = w.add_channel(s2, "/bass/t/audio", "cdr", &meta).unwrap();
    let (mut buf, mut seq, mut losses) = (Vec::new(), 0u32, Vec::new());
    for &(first, chunks, lost_before) in runs {
        if lost_before > 0 {
            losses.push(Lost { first_frame: first - lost_before, frames: lost_before });
        }
        for k in 0..chunks {
            let f = first + 100 * k;
            let (bound_ns, missing_channels, unaligned_channels) = mcap_ext(f);
            let info = ChunkInfo {
                header: Header { stamp: Time::from_ns(f * 125_000), frame_id: String::new() },
                epoch: 1,
                first_frame: f,
                frames: 100,
                chunk_first_frame: f,
                chunk_frames: 100,
                flags: 0,
                monotonic_ns: f * 125_000,
                realtime_ns: f * 125_000,
                lost_before: if k == 0 { lost_before } else { 0 },
                bound_ns,
                missing_channels,
                unaligned_channels,
            };
            let h = |channel_id| mcap::records::MessageHeader {
                channel_id,
                sequence: seq,
                log_time: f,
                publish_time: f,
            };
            info.encode(&mut buf);
            if old {
                buf.truncate(buf.len() - 24);
            }
            w.write_to_known_channel(&h(c1), &buf).unwrap();
            let s: Vec<i32> = (f..f + 100).map(|x| x as i32).collect();
            AudioDataStamped::encode_samples(&info.header, &s, &mut buf);
            w.write_to_known_channel(&h(c2), &buf).unwrap();
            seq += 1;
        }
    }
    let (last_run, chunks, _) = *runs.last().unwrap();
    let end = last_run + 100 * chunks;
    if end <= frames {
        losses.push(Lost { first_frame: end, frames: frames - end + 1 });
    }
    let lost_frames = losses.iter().map(|l| l.frames).sum();
    let facts = Sidecar {
        acquisition: Acquisition {
            device: "sim:pattern".into(),
            format: "S32_LE".into(),
            sample_rate: 8000,
            channels: 1,
            frames_per_chunk: 100,
            chunks_on_port: 200,
            epoch: 1,
        },
        recording: Recording {
            file: name.into(),
            first_frame: 1,
            frames,
            seconds: frames as f64 / 8000.0,
            bytes: 0,
            bits: 32,
            channels: vec![0],
            gap_frames: 0,
            lost_frames,
            end: "limit".into(),
            requested_first_frame: None,
            started_after_requested: 0,
            wav_format: None,
            in_progress: false,
        },
        losses,
        chunks: Vec::new(),
    };
    let md = BTreeMap::from([("sidecar".to_string(), serde_json::to_string(&facts).unwrap())]);
    w.write_metadata(&mcap::records::Metadata { name: "bass".into(), metadata: md }).unwrap();
    w.finish().unwrap();
    let p = dir.join(name);
    std::fs::write(&p, w.into_inner().into_inner()).unwrap();
    p
}

/// Reads the port from frame 1 until the replay has ended and every frame is read: the
/// frames delivered (checked: sample = frame index) and the loss reported, as (first frame
/// of a block after a loss, loss) pairs and the frames delivered.
fn read_to_the_end(port: &bassport::Port) -> (Vec<(u64, u64)>, Vec<u64>) {
    let (mut out, mut nfr, mut losses, mut got) = (vec![0; 20_000], 1u64, Vec::new(), Vec::new());
    let deadline = std::time::Instant::now() + PATIENCE;
    loop {
        let ended = port.info().unwrap().state == Some(State::Stopped);
        let r = port.get_audio_data(out.len(), &mut nfr, &mut [&mut out[..]]).unwrap();
        let first = nfr - r.frames as u64;
        if r.loss > 0 {
            losses.push((first, r.loss));
        }
        for (k, &s) in out[..r.frames].iter().enumerate() {
            assert_eq!(s, (first + k as u64) as i32, "frame {}", first + k as u64);
            got.push(first + k as u64);
        }
        if ended && r.frames == 0 && r.loss == 0 {
            return (losses, got);
        }
        assert!(std::time::Instant::now() < deadline, "the replay did not end: {:?}", port.info().unwrap());
        if r.frames == 0 {
            let _ = port.wait(nfr, std::time::Duration::from_millis(20));
        }
    }
}

/// The capture threads of process `pid` (by name, from /proc/PID/task/*/comm).
fn capture_threads(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/task"))
        .unwrap()
        .filter_map(|t| std::fs::read_to_string(t.unwrap().path().join("comm")).ok())
        .filter(|c| c.trim() == "bassd-capture")
        .count()
}

#[test]
fn an_hour_long_loss_inside_a_recording_is_replayed_as_that_loss_at_once() {
    // Frames 1..=200, a loss of 60 minutes at 8000 Hz (28.8 M frames), frames ..=28_800_400.
    // Before the fix the replay stepped through the lost frames one by one, then waited out
    // the hour: no frame after the loss within any patience.
    const LOST: u64 = 60 * 60 * 8000;
    let dir = TempDir::new("replay-long-loss");
    let b = Bassd::start_replaying(dir.path(), "default");
    let p = mcap_recording(dir.path(), "hour.mcap", &[(1, 2, 0), (201 + LOST, 2, LOST)], 400 + LOST);
    let dev = format!("sim:file:{}", p.display());
    b.client().acquire(&acquire_req(&dev, 8000, 100, 200, 1)).unwrap();
    let port = b.port();
    let (losses, got) = read_to_the_end(&port);
    let info = port.info().unwrap();
    assert_eq!(info.error_code, error_code::NONE, "{}", info.message);
    assert!(info.message.contains(&format!("{LOST} lost as in the recording")), "{}", info.message);
    assert_eq!((info.last_frame_index, info.lost_upstream_frames), (400 + LOST, LOST));
    // Every frame read or counted lost; the frames after the loss at their recorded indices.
    let lost: u64 = losses.iter().map(|l| l.1).sum();
    assert_eq!(got.len() as u64 + lost, 400 + LOST);
    let after: Vec<u64> = got.iter().copied().filter(|&f| f > 200).collect();
    assert_eq!(after, (201 + LOST..=400 + LOST).collect::<Vec<_>>());
    assert!(lost >= LOST && losses.iter().all(|&(f, _)| f == 201 + LOST || f <= 201), "{losses:?}");
    assert!(!b.log_text().contains("stalled"), "{}", b.log_text());
}

#[test]
fn a_loss_to_the_end_of_a_recording_is_replayed_and_leaves_no_capture_thread_behind() {
    // Frames 1..=200, then lost to the end: 180 minutes at 8000 Hz, and a forged recording
    // lost to frame 2^53 (the largest a replay accepts). Before the fix the replay stepped
    // through the lost frames one by one, on a thread a Stop could not end ("leaving it behind").
    let dir = TempDir::new("replay-loss-to-end");
    let mut b = Bassd::start_replaying(dir.path(), "default");
    for (name, frames) in [("end.mcap", 200 + 180 * 60 * 8000), ("forged.mcap", 1u64 << 53)] {
        let p = mcap_recording(dir.path(), name, &[(1, 2, 0)], frames);
        let dev = format!("sim:file:{}", p.display());
        b.client().acquire(&acquire_req(&dev, 8000, 100, 200, 1)).unwrap();
        let port = b.port();
        let (losses, got) = read_to_the_end(&port);
        let info = port.info().unwrap();
        assert_eq!(info.error_code, error_code::NONE, "{name}: {}", info.message);
        // The port moved on to the loss's last whole chunk; readers count all of it lost.
        let last = frames / 100 * 100;
        assert_eq!((info.last_frame_index, info.lost_upstream_frames), (last, frames - 200), "{name}");
        assert!(
            info.message.contains(&format!("{} lost as in the recording", frames - 200)),
            "{}",
            info.message
        );
        let lost: u64 = losses.iter().map(|l| l.1).sum();
        assert_eq!(got.len() as u64 + lost, frames, "{name}: {losses:?}");
        assert!(got.iter().all(|&f| f <= 200), "{name}: {got:?}");
        b.client().stop().unwrap();
        assert_eq!(capture_threads(b.pid()), 0, "{name}: a capture thread is left");
    }
    // One frame further is refused by name.
    let p = mcap_recording(dir.path(), "past.mcap", &[(1, 2, 0)], (1 << 53) + 1);
    let dev = format!("sim:file:{}", p.display());
    let e = b.client().acquire(&acquire_req(&dev, 8000, 100, 200, 1)).unwrap_err().to_string();
    assert!(e.contains("runs past frame 9007199254740992 (2^53)"), "{e}");
    assert!(!b.log_text().contains("leaving it behind"), "{}", b.log_text());
    b.signal(libc::SIGTERM);
    assert!(b.wait_exit().success());
}

/// Replays `dev` (1 or 2 channels at 8000 Hz, 100-frame chunks) to its end and gives the bound
/// and masks of the port's chunks at frames `first`, `first + 100`, ... (`chunks` of them).
fn replayed_ext(b: &Bassd, dev: &str, channels: u32, first: u64, chunks: u64) -> Vec<(u64, u64, u64)> {
    b.client().acquire(&acquire_req(dev, 8000, 100, 200, channels)).unwrap();
    let port = b.port();
    replay_end(&port);
    (0..chunks)
        .map(|k| port.chunk_info(first + 100 * k).unwrap())
        .map(|ci| (ci.bound_ns, ci.missing_channels, ci.unaligned_channels))
        .collect()
}

#[test]
fn a_replayed_mcap_recording_gives_each_chunk_its_recorded_bound_and_masks() {
    let dir = TempDir::new("replay-mcap-bound");
    let b = Bassd::start_replaying(dir.path(), "default");
    let want: Vec<_> = (0..6u64).map(|k| mcap_ext(100 * k + 1)).collect();
    assert_eq!(&want[..3], [(7, 0, 0), (1007, 1, 0), (u64::MAX, 0, 1)], "values that differ per chunk");
    let p = mcap_recording(dir.path(), "bound.mcap", &[(1, 6, 0)], 600);
    assert_eq!(replayed_ext(&b, &format!("sim:file:{}", p.display()), 1, 1, 6), want);
    // A recording of an older bass: ChunkInfo without the three fields, replayed as not known.
    let p = mcap_recording_as(dir.path(), "old.mcap", &[(1, 6, 0)], 600, true);
    let got = replayed_ext(&b, &format!("sim:file:{}", p.display()), 1, 1, 6);
    assert_eq!(got, vec![(u64::MAX, 0, 0); 6]);
}

#[test]
fn a_replayed_wav_recording_gives_each_chunk_its_recorded_bound_and_masks() {
    let dir = TempDir::new("replay-wav-bound");
    let b = Bassd::start_replaying(dir.path(), "default");
    let wav = record(&b, "sim:pattern", 100, 800, "b.wav");
    let dev = format!("sim:file:{}", wav.display());
    let side_path = basskit::sidecar::path_of(&wav);
    let side: serde_json::Value = serde_json::from_slice(&std::fs::read(&side_path).unwrap()).unwrap();
    // The capture's bounds, as recorded: every chunk has one, and the replay gives them back.
    let rows = side["chunks"].as_array().unwrap();
    let captured: Vec<(u64, u64, u64)> =
        rows.iter().map(|r| (r["bound_ns"].as_u64().expect("a captured chunk has a bound"), 0, 0)).collect();
    assert_eq!(captured.len(), 8);
    assert_eq!(replayed_ext(&b, &dev, 2, 1, 8), captured);
    // Values set per chunk in the sidecar (channel 1 missing where the row says so is not
    // zeros in this file: the replay gives the masks as recorded, it does not check them).
    let ext = |k: u64| {
        let bound = if k % 3 == 2 { None } else { Some(1000 * k + 7) };
        (bound, k & 2, k & 3)
    };
    let mut edited = side.clone();
    for (k, r) in edited["chunks"].as_array_mut().unwrap().iter_mut().enumerate() {
        let (bound, missing, unaligned) = ext(k as u64);
        r["bound_ns"] = bound.map_or(serde_json::Value::Null, Into::into);
        r["missing_channels"] = missing.into();
        r["unaligned_channels"] = unaligned.into();
    }
    std::fs::write(&side_path, serde_json::to_vec(&edited).unwrap()).unwrap();
    let want: Vec<_> = (0..8).map(ext).map(|(b, m, u)| (b.unwrap_or(u64::MAX), m, u)).collect();
    assert_eq!(&want[..3], [(7, 0, 0), (1007, 0, 1), (u64::MAX, 2, 2)], "values that differ per chunk");
    assert_eq!(replayed_ext(&b, &dev, 2, 1, 8), want);
    // A sidecar of an older recorder: rows without the fields replay as not known and 0.
    let mut old = side;
    for r in old["chunks"].as_array_mut().unwrap() {
        let r = r.as_object_mut().unwrap();
        r.remove("bound_ns");
        r.remove("missing_channels");
        r.remove("unaligned_channels");
    }
    std::fs::write(&side_path, serde_json::to_vec(&old).unwrap()).unwrap();
    assert_eq!(replayed_ext(&b, &dev, 2, 1, 8), vec![(u64::MAX, 0, 0); 8]);
}
