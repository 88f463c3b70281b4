//! MCAP recordings written here with the mcap crate and bass's ROS 2 messages, read back by
//! the replay's reader: the frames and the sidecar they amount to, and every bad value named.

use std::collections::BTreeMap;
use std::io::Cursor;

use basskit::ros2::{self, AudioDataStamped, ChunkInfo, Header, Time};
use basskit::sidecar::{Acquisition, Lost, Recording, Sidecar};
use bassport::format::chunk_flags;

use super::*;

/// The bound and masks [`run`] gives chunk `chunk`: bound 10·chunk (unknown for chunk 401),
/// channel 0 missing in chunk 201 and unaligned in chunk 501.
fn ext_of(chunk: u64) -> (u64, u64, u64) {
    let bound = if chunk == 401 { ros2::BOUND_UNKNOWN } else { chunk * 10 };
    (bound, u64::from(chunk == 201), u64::from(chunk == 501))
}

/// A run of frames for [`write`]: its ChunkInfo (frames and chunk fields filled in).
fn run(first: u64, frames: u32, lost_before: u64, flags: u32) -> ChunkInfo {
    let chunk = (first - 1) / 100 * 100 + 1;
    let (bound_ns, missing_channels, unaligned_channels) = ext_of(chunk);
    ChunkInfo {
        header: Header { stamp: Time::from_ns(first * 1000), frame_id: String::new() },
        epoch: 3,
        first_frame: first,
        frames,
        chunk_first_frame: chunk,
        chunk_frames: 100,
        flags,
        monotonic_ns: chunk * 10,
        realtime_ns: chunk * 1000,
        lost_before,
        bound_ns,
        missing_channels,
        unaligned_channels,
    }
}

/// The facts of a recording of frames 151..=550 (1 channel, 100-frame chunks) losing 301..=400.
fn facts() -> Sidecar {
    Sidecar {
        acquisition: Acquisition {
            device: "sim:pattern".into(),
            format: "S32_LE".into(),
            sample_rate: 8000,
            channels: 1,
            frames_per_chunk: 100,
            chunks_on_port: 20,
            epoch: 3,
        },
        recording: Recording {
            file: "r".into(),
            first_frame: 151,
            frames: 400,
            seconds: 0.05,
            bytes: 0,
            bits: 32,
            channels: vec![0],
            gap_frames: 0,
            lost_frames: 100,
            end: "limit".into(),
            requested_first_frame: None,
            started_after_requested: 0,
            wav_format: None,
            in_progress: false,
        },
        losses: vec![Lost { first_frame: 301, frames: 100 }],
        chunks: Vec::new(),
    }
}

fn good_runs() -> Vec<ChunkInfo> {
    vec![run(151, 50, 0, 0), run(201, 100, 0, 0), run(401, 100, 100, 0), run(501, 50, 0, 0)]
}

/// An MCAP file of `runs` (sample = frame index) and `facts` (no metadata record if None);
/// `data_frames` overrides the frames of audio held by run `i`.
fn write(
    dir: &Path,
    name: &str,
    runs: &[ChunkInfo],
    facts: Option<&Sidecar>,
    bad_data: Option<usize>,
) -> PathBuf {
    write_as(dir, name, runs, facts, bad_data, false)
}

/// The ChunkInfo definition of bass before port format 2.4: without its last three fields.
fn old_definition() -> String {
    let d = ros2::CHUNK_INFO_DEFINITION;
    let cut = d.find("uint64 bound_ns").expect("the bound's line");
    let rest = &d[d.find("uint64 unaligned_channels").unwrap()..];
    format!("{}{}", &d[..cut], &rest[rest.find('\n').unwrap() + 1..])
}

/// [`write`], with the ChunkInfo messages and schema of an older recorder if `old`.
fn write_as(
    dir: &Path,
    name: &str,
    runs: &[ChunkInfo],
    facts: Option<&Sidecar>,
    bad_data: Option<usize>,
    old: bool,
) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let mut w =
        mcap::WriteOptions::new().profile("ros2").compression(None).create(Cursor::new(Vec::new())).unwrap();
    let meta = BTreeMap::new();
    let def = if old { old_definition() } else { ros2::CHUNK_INFO_DEFINITION.to_string() };
    let s1 = w.add_schema(ros2::CHUNK_INFO, "ros2msg", def.as_bytes()).unwrap();
    let c1 = w.add_channel(s1, "/bass/t/chunk_info", "cdr", &meta).unwrap();
    let s2 = w
        .add_schema(ros2::AUDIO_DATA_STAMPED, "ros2msg", ros2::AUDIO_DATA_STAMPED_DEFINITION.as_bytes())
        .unwrap();
    let c2 = w.add_channel(s2, "/bass/t/audio", "cdr", &meta).unwrap();
    let mut buf = Vec::new();
    for (i, r) in runs.iter().enumerate() {
        let h = |channel_id| mcap::records::MessageHeader {
            channel_id,
            sequence: i as u32,
            log_time: r.first_frame,
            publish_time: r.first_frame,
        };
        r.encode(&mut buf);
        if old {
            buf.truncate(buf.len() - 24); // the message ended at lost_before
        }
        w.write_to_known_channel(&h(c1), &buf).unwrap();
        let n = if bad_data == Some(i) { u64::from(r.frames) - 1 } else { u64::from(r.frames) };
        let s: Vec<i32> = (r.first_frame..r.first_frame + n).map(|f| f as i32).collect();
        AudioDataStamped::encode_samples(&r.header, &s, &mut buf);
        w.write_to_known_channel(&h(c2), &buf).unwrap();
    }
    if let Some(f) = facts {
        let md = BTreeMap::from([("sidecar".to_string(), serde_json::to_string(f).unwrap())]);
        w.write_metadata(&mcap::records::Metadata { name: "bass".into(), metadata: md }).unwrap();
    }
    w.finish().unwrap();
    let bytes = w.into_inner().into_inner();
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn open_path(p: &Path) -> Result<(McapFrames, Sidecar), String> {
    open(p, File::open(p).unwrap())
}

fn tmp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("bass-mcap-{}-{name}", std::process::id()))
}

#[test]
fn a_recording_reads_back_as_its_frames_and_sidecar_with_losses_as_zeros() {
    let dir = tmp("good");
    let p = write(&dir, "r.mcap", &good_runs(), Some(&facts()), None);
    let (mut frames, side) = open_path(&p).unwrap();
    assert_eq!(side.problems(), Vec::<String>::new());
    let rows: Vec<u64> = side.chunks.iter().map(|r| r.first_frame).collect();
    assert_eq!(rows, [101, 201, 401, 501], "one row per chunk, none for the lost one");
    assert_eq!((side.chunks[0].realtime_ns, side.chunks[0].mono_ns), (101_000, 1010));
    let ext: Vec<_> = side
        .chunks
        .iter()
        .map(|r| (r.bound_or_unknown(), r.missing_channels, r.unaligned_channels))
        .collect();
    assert_eq!(ext, rows.iter().map(|&c| ext_of(c)).collect::<Vec<_>>(), "each row's bound and masks");
    assert_eq!((side.chunks[1].bound_ns, side.chunks[2].bound_ns), (Some(2010), None));
    // File frame i is frame 151 + i; frames 301..=400 were lost.
    let mut out = vec![0; 400];
    frames.fill(0, &mut out, 400).unwrap();
    let want: Vec<i32> = (151..551).map(|f| if (301..=400).contains(&f) { 0 } else { f }).collect();
    assert_eq!(out, want);
    // Reading again from the start (a loop) rewinds; a read in the middle continues.
    let mut part = vec![0; 10];
    frames.fill(0, &mut part, 10).unwrap();
    assert_eq!(part, (151..161).collect::<Vec<i32>>());
    frames.fill(245, &mut part, 10).unwrap();
    assert_eq!(part, (396..406).map(|f| if f <= 400 { 0 } else { f }).collect::<Vec<i32>>());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn every_bad_value_is_refused_by_name() {
    let dir = tmp("bad");
    type Poke = fn(&mut Vec<ChunkInfo>, &mut Sidecar);
    let cases: Vec<(&str, Poke, Option<usize>, &str)> = vec![
        ("size", |r, _| r[1].chunk_frames = 50, None, "chunk_frames 50; the recording's chunks hold 100"),
        (
            "first",
            |r, _| r[2].first_frame = 405,
            None,
            "first_frame 405; after the message before it and lost_before 100 it must be 401",
        ),
        (
            "row",
            |r, _| r[1].chunk_first_frame = 101,
            None,
            "chunk_first_frame 101; its frames are in the chunk at 201",
        ),
        ("epoch", |r, _| r[0].epoch = 9, None, "epoch 9; the recording's is 3"),
        ("zero", |r, _| r[3].frames = 0, None, "frames 0"),
        ("long", |r, _| r[3].frames = 150, None, "150 frames pass the end of its chunk at frame 600"),
        (
            "data",
            |_, _| {},
            Some(2),
            "audio message 2: 396 bytes of data; 100 frames of 1 S32LE channels are 400",
        ),
        ("losses", |_, f| f.losses[0].frames = 50, None, "the messages' lost_before make the losses"),
        ("flags", |r, _| r[1].flags = 0x40, None, "unknown flags 0x40"),
        (
            "mask",
            |r, _| r[1].unaligned_channels = 0b10,
            None,
            "unaligned_channels 0x2 names channel 1; the port has 1",
        ),
        (
            "end",
            |_, f| f.recording.frames = 300,
            None,
            "the messages reach frame 550; the recording ends at frame 450",
        ),
    ];
    for (name, poke, bad_data, want) in cases {
        let (mut runs, mut f) = (good_runs(), facts());
        poke(&mut runs, &mut f);
        let p = write(&dir, &format!("{name}.mcap"), &runs, Some(&f), bad_data);
        let e = open_path(&p).err().unwrap_or_else(|| panic!("{name}: accepted"));
        assert!(e.contains(want), "{name}: {want:?} not in {e:?}");
    }
    let p = write(&dir, "nofacts.mcap", &good_runs(), None, None);
    assert!(open_path(&p).err().unwrap().contains("no \"bass\" metadata record"));
    // Not MCAP at all, and an MCAP cut short: named, no panic.
    let junk = dir.join("junk.mcap");
    std::fs::write(&junk, b"RIFF....WAVEfmt ").unwrap();
    assert!(open_path(&junk).err().unwrap().contains("not a readable MCAP file"));
    let good = std::fs::read(write(&dir, "whole.mcap", &good_runs(), Some(&facts()), None)).unwrap();
    for cut in [good.len() / 3, good.len() - 30] {
        let short = dir.join("short.mcap");
        std::fs::write(&short, &good[..cut]).unwrap();
        assert!(open_path(&short).is_err(), "cut at {cut} of {}", good.len());
    }
    // One sample changed after the file was written: the chunk's CRC refuses it.
    let mut flipped = good.clone();
    let at = flipped.windows(4).position(|w| w == 221i32.to_le_bytes()).expect("frame 221 sample");
    flipped[at] ^= 1;
    let p = dir.join("flipped.mcap");
    std::fs::write(&p, &flipped).unwrap();
    let e = open_path(&p).err().expect("a changed sample is refused");
    assert!(e.contains("crc") || e.contains("CRC"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_older_recording_without_the_bound_reads_as_unknown_and_no_channel() {
    let dir = tmp("old");
    let def = old_definition();
    assert!(
        !def.contains("bound_ns") && !def.contains("_channels") && def.contains("MSG: std_msgs/Header"),
        "{def}"
    );
    let p = write_as(&dir, "old.mcap", &good_runs(), Some(&facts()), None, true);
    let (mut frames, side) = open_path(&p).unwrap();
    let ext: Vec<_> =
        side.chunks.iter().map(|r| (r.bound_ns, r.missing_channels, r.unaligned_channels)).collect();
    assert_eq!(ext, [(None, 0, 0); 4]);
    let mut out = vec![0; 50];
    frames.fill(0, &mut out, 50).unwrap();
    assert_eq!(out, (151..201).collect::<Vec<i32>>());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_bag_directory_resolves_to_its_one_mcap_file() {
    let dir = tmp("bag");
    let p = write(&dir, "bag_0.mcap", &good_runs(), Some(&facts()), None);
    std::fs::write(dir.join("metadata.yaml"), "rosbag2_bagfile_information: {}\n").unwrap();
    assert!(is_mcap(&dir) && is_mcap(&p));
    assert_eq!(resolve(&dir).unwrap(), p);
    write(&dir, "other.mcap", &good_runs(), Some(&facts()), None);
    assert!(resolve(&dir).err().unwrap().contains("holds 2 .mcap files"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_first_pass_over_gap_chunks_with_losses_is_linear() {
    // n GAP chunks, each losing 10 of its frames: n rows and n losses, which the first pass
    // used to compare pairwise (n², 4·10⁸ for 20 000 chunks: 15.9 s for a 48.7 MB file).
    let dir = tmp("linear");
    for n in [10u64, 20_000] {
        let mut runs = Vec::new();
        for k in 0..n {
            runs.push(run(1 + 100 * k, 40, 0, chunk_flags::GAP));
            runs.push(run(51 + 100 * k, 50, 10, chunk_flags::GAP));
        }
        let mut f = facts();
        f.losses = (0..n).map(|k| Lost { first_frame: 41 + 100 * k, frames: 10 }).collect();
        let r = &mut f.recording;
        (r.first_frame, r.frames, r.lost_frames, r.gap_frames) = (1, 100 * n, 10 * n, 90 * n);
        let p = write(&dir, &format!("gaps{n}.mcap"), &runs, Some(&f), None);
        let t = std::time::Instant::now();
        let (_, side) = open_path(&p).unwrap();
        let bytes = std::fs::metadata(&p).unwrap().len();
        println!("{n} GAP chunks with losses, {bytes} bytes: opened in {:?}", t.elapsed());
        assert_eq!((side.chunks.len() as u64, side.losses.len() as u64), (n, n));
        let (gap, steps) = side.gap_frames_walk();
        assert_eq!(gap, 90 * n);
        assert!(steps <= 3 * n + 1, "{steps} comparisons for {n} rows and {n} losses");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
