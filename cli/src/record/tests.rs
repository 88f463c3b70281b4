//! Unit tests of the recorder: conversion, --from, --check and the read loop.

use super::*;
use basskit::sidecar::{ChunkRow, Lost, Sidecar};
use bassport::Port;
use std::fs::File;
use std::path::Path;

#[test]
fn conversion_rounds_half_up_and_saturates() {
    assert_eq!(convert(0x1234_5678, 32), 0x1234_5678);
    assert_eq!(convert(0x0001_8000, 16), 2); // 1.5 -> 2
    assert_eq!(convert(0x0001_7fff, 16), 1);
    assert_eq!(convert(-0x0001_8000, 16), -1); // -1.5 -> -1 (half up)
    assert_eq!(convert(i32::MAX, 16), i16::MAX as i32);
    assert_eq!(convert(i32::MIN, 16), i16::MIN as i32);
    assert_eq!(convert(i32::MAX, 24), (1 << 23) - 1);
    assert_eq!(convert(0x100 * 77 + 0x80, 24), 78);
}

#[test]
fn from_accepts_oldest_now_and_frames() {
    assert_eq!(parse_from("oldest"), Ok(From::Oldest));
    assert_eq!(parse_from("now"), Ok(From::Now));
    assert_eq!(parse_from("12"), Ok(From::Frame(12)));
    assert!(parse_from("0").is_err() && parse_from("later").is_err());
}

/// A WAV of 400 frames (2 channels, 16 bits) from frame 151 with a loss of chunk 301..=400
/// (zeros) and the sidecar that describes it; `poke` changes the pair before writing.
fn pair(name: &str, poke: impl FnOnce(&mut Vec<i32>, &mut Sidecar)) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("bass-check-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("r.wav");
    let mut samples: Vec<i32> = (151..551u64)
        .flat_map(|f| [0, 1].map(|c| if (301..=400).contains(&f) { 0 } else { (f * 2 + c) as i32 }))
        .collect();
    let row = |f: u64, flags: u32| ChunkRow {
        first_frame: f,
        frames: 100,
        mono_ns: f,
        realtime_ns: f,
        flags,
        ..Default::default()
    };
    let mut side: Sidecar = serde_json::from_value(serde_json::json!({
        "acquisition": {"device": "sim:pattern", "format": "S32_LE", "sample_rate": 8000, "channels": 2,
                        "frames_per_chunk": 100, "chunks_on_port": 20, "epoch": 1},
        "recording": {"file": "r.wav", "first_frame": 151, "frames": 400, "seconds": 0.05, "bytes": 44 + 1600,
                      "bits": 16, "channels": [0, 1], "gap_frames": 0, "lost_frames": 100, "end": "limit",
                      "wav_format": "pcm"},
        "losses": [{"first_frame": 301, "frames": 100}],
    }))
    .unwrap();
    side.chunks = vec![row(101, 0), row(201, 0), row(401, 0), row(501, 0)];
    poke(&mut samples, &mut side);
    let spec = wav::Spec { channels: 2, sample_rate: 8000, bits: 16, format: wav::Format::Pcm };
    let mut w = wav::Writer::new(File::create(&path).unwrap(), spec).unwrap();
    for s in samples {
        w.sample(s).unwrap();
    }
    w.finalize().unwrap();
    std::fs::write(sidecar::path_of(&path), serde_json::to_vec(&side).unwrap()).unwrap();
    path
}

#[test]
fn check_accepts_a_pair_that_agrees_and_names_each_disagreement() {
    let done = |p: &Path| std::fs::remove_dir_all(p.parent().unwrap()).unwrap();
    let p = pair("ok", |_, _| {});
    let ok = check(&p).unwrap();
    done(&p);
    assert!(ok.starts_with("ok: ") && ok.contains("400 frames") && ok.contains("100 frames lost"), "{ok}");
    type Poke = Box<dyn FnOnce(&mut Vec<i32>, &mut Sidecar)>;
    let cases: Vec<(&str, Poke, &str)> = vec![
        ("lost", Box::new(|s, _| s[(350 - 151) * 2] = 7), "lost frame 350 is not zero"),
        ("gap", Box::new(|_, d| d.chunks[3].flags = 1), "gap_frames is 0; the GAP chunks hold 50"),
        (
            "gapdata",
            Box::new(|_, d| {
                d.chunks[3].flags = 1;
                d.recording.gap_frames = 50;
            }),
            "GAP frame 501 is not zero",
        ),
        ("frames", Box::new(|s, _| s.truncate(399 * 2)), "the WAV holds 399 frames; the sidecar says 400"),
        ("format", Box::new(|_, d| d.recording.wav_format = Some("extensible".into())), "header is pcm"),
        ("bits", Box::new(|_, d| d.recording.bits = 24), "16 bits per sample; the sidecar says 24"),
        (
            "missing",
            Box::new(|_, d| d.chunks[3].missing_channels = 0b10),
            "missing-channel frame 501 is not zero in the WAV (frames 501..=550 must be, in file channel 1)",
        ),
        (
            "mask",
            Box::new(|_, d| d.chunks[0].unaligned_channels = 0b100),
            "unaligned_channels 0x4 names channel 2",
        ),
    ];
    for (name, poke, want) in cases {
        let path = pair(name, poke);
        let p = check(&path).unwrap_err();
        done(&path);
        assert!(p.iter().any(|m| m.contains(want)), "{name}: {want:?} not in {p:?}");
    }
    // A missing channel that is zero in the WAV (its frames as the device left them) agrees.
    let p = pair("missing-ok", |s, d| {
        d.chunks[3].missing_channels = 0b10;
        d.chunks[3].bound_ns = Some(1);
        (501..=550).for_each(|f| s[(f - 151) * 2 + 1] = 0);
    });
    let ok = check(&p);
    done(&p);
    assert!(ok.is_ok(), "{ok:?}");
    let p = check(Path::new("/nonexistent/r.wav")).unwrap_err();
    assert!(p[0].contains("no sidecar"), "{p:?}");
}

/// A port of 4 chunks of 10 frames (1 channel, sample = frame index) written in this
/// process, and a recording of it from `from` into a WAV in `dir`.
fn rig(dir: &Path, from: u64) -> (bassport::Writer, Port, Recording) {
    use bassport::{Geometry, PortParams};
    std::fs::create_dir_all(dir).unwrap();
    let geometry = Geometry { channels: 1, sample_rate: 8000, frames_per_chunk: 10, chunks_on_port: 4 };
    let path = dir.join("rec.port");
    let w = bassport::Writer::create_at(&path, &PortParams { geometry, device: "unit".into(), group: None })
        .unwrap();
    let port = Port::open_path(&path).unwrap();
    let file = dir.join("r.wav");
    let spec = wav::Spec { channels: 1, sample_rate: 8000, bits: 32, format: wav::Format::Pcm };
    let rec = Recording {
        side_path: sidecar::path_of(&file),
        out: Out::Wav(wav::Writer::new(File::create(&file).unwrap(), spec).unwrap()),
        file,
        acquisition: sidecar::Acquisition {
            device: "unit".into(),
            format: "S32_LE".into(),
            sample_rate: 8000,
            channels: 1,
            frames_per_chunk: 10,
            chunks_on_port: 4,
            epoch: port.epoch(),
        },
        channels: vec![0],
        requested: from,
        first: None,
        next: from,
        rows: Vec::new(),
        gap_count: 0,
        losses: Vec::new(),
    };
    (w, port, rec)
}

/// The bound and the unaligned mask `publish` gives the chunk starting at `first`: chunk k
/// (from 1) has bound 1000·k, unknown for every third, and channel 0 unaligned in odd chunks.
fn ext_of(first: u64) -> (Option<u64>, u64) {
    let k = (first - 1) / 10 + 1;
    ((k % 3 != 0).then_some(1000 * k), k & 1)
}

fn publish(w: &mut bassport::Writer, chunks: u64) {
    for _ in 0..chunks {
        let lfi = w.last_frame_index();
        let s: Vec<i32> = (lfi + 1..=lfi + 10).map(|f| f as i32).collect();
        let (bound_ns, unaligned_channels) = ext_of(lfi + 1);
        let meta = bassport::ChunkMeta { bound_ns, unaligned_channels, ..Default::default() };
        w.publish(bassport::Source::Interleaved(&s), meta).unwrap();
    }
}

fn samples(rec: &mut Recording) -> Vec<i32> {
    let Out::Wav(w) = &mut rec.out else { panic!("a WAV recording") };
    w.checkpoint().unwrap();
    hound::WavReader::open(&rec.file).unwrap().samples::<i32>().map(|s| s.unwrap()).collect()
}

#[test]
fn reads_end_on_chunks_so_a_loss_starts_on_a_chunk_and_whole_chunks_have_rows() {
    let dir = std::env::temp_dir().join(format!("bass-rec-unit-{}-loss", std::process::id()));
    let (mut w, port, mut rec) = rig(&dir, 5);
    let mut peaks = [0.0];
    publish(&mut w, 3);
    // Frames 5..=20 (to the end of a chunk: at most 2 chunks a read with this window).
    assert!(rec.step(&port, None, &mut peaks).is_ok());
    assert_eq!((rec.first, rec.next), (Some(5), 21));
    // The port moves on by 10 chunks: frames 21..=90 are lost, from a chunk start.
    publish(&mut w, 10);
    while rec.next <= 130 {
        assert!(rec.step(&port, None, &mut peaks).is_ok());
    }
    assert_eq!(rec.losses, [Lost { first_frame: 21, frames: 70 }]);
    let rows: Vec<u64> = rec.rows.iter().map(|r| r.first_frame).collect();
    assert_eq!(rows, [1, 11, 91, 101, 111, 121], "a row for every chunk read, none for lost ones");
    let side = rec.sidecar(rec.out.frames(), "limit", false);
    assert_eq!(side.problems(), Vec::<String>::new());
    assert_eq!((side.recording.first_frame, side.recording.frames), (5, 126));
    let want: Vec<i32> = (5..=130).map(|f| if (21..=90).contains(&f) { 0 } else { f }).collect();
    assert_eq!(samples(&mut rec), want);
    // Each row's bound and mask, as the port had them, through the sidecar file and back.
    let side = rec.finish("limit", false).unwrap().side;
    let back = Sidecar::load_for(&rec.file).unwrap().unwrap();
    assert_eq!(back, side);
    let ext: Vec<_> =
        back.chunks.iter().map(|r| (r.bound_ns, r.unaligned_channels, r.missing_channels)).collect();
    let want: Vec<_> = rows.iter().map(|&f| (ext_of(f).0, ext_of(f).1, 0)).collect();
    assert_eq!(ext, want);
    assert_eq!(&want[..2], [(Some(1000), 1, 0), (Some(2000), 0, 0)], "the rows differ: chunks 1 and 2");
    assert_eq!(want[4], (None, 0, 0), "chunk 12's bound is not known");
    assert!(check(&rec.file).is_ok());
    drop(port);
    w.remove().unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_start_the_port_no_longer_has_starts_the_file_at_its_oldest_chunk() {
    let dir = std::env::temp_dir().join(format!("bass-rec-unit-{}-late", std::process::id()));
    let (mut w, port, mut rec) = rig(&dir, 5);
    let mut peaks = [0.0];
    publish(&mut w, 13); // frames 91..=130 on the port
    while rec.next <= 130 {
        assert!(rec.step(&port, Some(25), &mut peaks).is_ok());
        if rec.out.frames() == 25 {
            break;
        }
    }
    assert!(rec.losses.is_empty(), "no loss inside the file");
    let side = rec.sidecar(rec.out.frames(), "limit", false);
    let r = &side.recording;
    assert_eq!(
        (r.first_frame, r.frames, r.requested_first_frame, r.started_after_requested),
        (91, 25, Some(5), 86)
    );
    assert_eq!(side.problems(), Vec::<String>::new());
    assert_eq!(samples(&mut rec), (91..116).collect::<Vec<i32>>(), "the limit counts from the file's start");
    drop(port);
    w.remove().unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Every message of the MCAP file `path`: (topic, sequence, payload), in file order.
fn mcap_messages(path: &Path) -> Vec<(String, u32, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            (m.channel.topic.clone(), m.sequence, m.data.into_owned())
        })
        .collect()
}

#[test]
fn an_mcap_recording_holds_every_frame_once_and_a_loss_in_no_message() {
    use basskit::ros2::{AudioDataStamped, AudioInfo, ChunkInfo};
    let dir = std::env::temp_dir().join(format!("bass-rec-unit-{}-mcap", std::process::id()));
    let (mut w, port, mut rec) = rig(&dir, 5);
    let bag = dir.join("bag");
    std::fs::create_dir_all(&bag).unwrap();
    let f = File::create(mcap_out::file_in(&bag)).unwrap();
    let layout = mcap_out::Layout::of(&bag);
    rec.out =
        Out::Mcap(Box::new(mcap_out::McapOut::new(&layout, f, "unit", 1, 8000, 10, port.epoch()).unwrap()));
    // Issue 31: links planted at metadata.yaml's temporary name and at metadata.yaml itself
    // are not followed: their targets stay as they were.
    let victims = [dir.join("victim-tmp"), dir.join("victim-yaml")];
    for v in &victims {
        std::fs::write(v, "keep").unwrap();
    }
    std::os::unix::fs::symlink(&victims[0], bag.join(".metadata.yaml.tmp")).unwrap();
    std::os::unix::fs::symlink(&victims[1], bag.join("metadata.yaml")).unwrap();
    let mut peaks = [0.0];
    publish(&mut w, 3);
    assert!(rec.step(&port, None, &mut peaks).is_ok()); // frames 5..=20
    publish(&mut w, 10); // 21..=90 leave the window
    while rec.next <= 130 {
        assert!(rec.step(&port, None, &mut peaks).is_ok());
    }
    let side = rec.finish("limit", false).unwrap().side;
    assert_eq!((side.recording.first_frame, side.recording.frames, side.recording.lost_frames), (5, 126, 70));
    assert!(bag.join("metadata.yaml").exists());
    assert!(!std::fs::symlink_metadata(bag.join("metadata.yaml")).unwrap().file_type().is_symlink());
    for v in &victims {
        assert_eq!(std::fs::read_to_string(v).unwrap(), "keep", "{} written through a link", v.display());
    }
    let msgs = mcap_messages(&mcap_out::file_in(&bag));
    assert_eq!(msgs[0].0, "/bass/unit/audio_info");
    assert_eq!(AudioInfo::decode(&msgs[0].2).unwrap(), AudioInfo::s32le(1, 8000));
    let mut frames = Vec::new();
    let mut runs = Vec::new();
    for pair in msgs[1..].chunks(2) {
        let (c, a) = (&pair[0], &pair[1]);
        assert_eq!((c.0.as_str(), a.0.as_str(), c.1), ("/bass/unit/chunk_info", "/bass/unit/audio", a.1));
        let ci = ChunkInfo::decode(&c.2).unwrap();
        let s = AudioDataStamped::decode(&a.2).unwrap().samples().unwrap();
        assert_eq!(s.len(), ci.frames as usize);
        runs.push((ci.first_frame, ci.frames, ci.chunk_first_frame, ci.lost_before));
        let (bound, unaligned) = ext_of(ci.chunk_first_frame);
        assert_eq!(
            (ci.bound_ns, ci.unaligned_channels, ci.missing_channels),
            (bound.unwrap_or(basskit::ros2::BOUND_UNKNOWN), unaligned, 0),
            "chunk {}",
            ci.chunk_first_frame
        );
        frames.extend(s);
    }
    assert_eq!(
        runs,
        [
            (5, 6, 1, 0),
            (11, 10, 11, 0),
            (91, 10, 91, 70),
            (101, 10, 101, 0),
            (111, 10, 111, 0),
            (121, 10, 121, 0)
        ],
        "a message per chunk part in the file; the loss before frame 91 counted, not sent"
    );
    let want: Vec<i32> = (5..=20).chain(91..=130).collect();
    assert_eq!(frames, want, "every sample once, none for the lost frames");
    // --check reads it back: the messages against the facts.
    let line = check_mcap(&bag).unwrap();
    assert!(line.contains("126 frames") && line.contains("70 frames lost in 1 losses"), "{line}");
    let file = mcap_out::file_in(&bag);
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..bytes.len() / 2]).unwrap();
    let problems = check_mcap(&file).unwrap_err();
    assert!(problems[0].contains("not a readable MCAP file"), "{problems:?}");
    drop(port);
    w.remove().unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}
