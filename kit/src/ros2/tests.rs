//! Unit tests of the ROS 2 messages: byte layout, alignment, round trips, refusals.

use super::*;

fn header(frame_id: &str) -> Header {
    Header { stamp: Time { sec: 1_700_000_123, nanosec: 456_789 }, frame_id: frame_id.into() }
}

#[test]
fn audio_data_stamped_has_the_documented_bytes() {
    let mut b = Vec::new();
    AudioDataStamped::encode_samples(&header("mic"), &[1, -1], &mut b);
    let mut want = CDR_LE.to_vec();
    want.extend_from_slice(&1_700_000_123i32.to_le_bytes());
    want.extend_from_slice(&456_789u32.to_le_bytes());
    want.extend_from_slice(&4u32.to_le_bytes()); // "mic" + NUL
    want.extend_from_slice(b"mic\0");
    want.extend_from_slice(&8u32.to_le_bytes());
    want.extend_from_slice(&[1, 0, 0, 0, 0xff, 0xff, 0xff, 0xff]);
    assert_eq!(b, want);
}

#[test]
fn the_sequence_length_is_aligned_after_any_frame_id() {
    // frame_id of 0..=4 characters: the string ends at 12 + len + 1, the u32 count at the
    // next multiple of 4.
    for n in 0..=4usize {
        let id = "x".repeat(n);
        let mut b = Vec::new();
        AudioDataStamped::encode_samples(&header(&id), &[7], &mut b);
        let count_at = (12 + n + 1).next_multiple_of(4);
        assert_eq!(&b[4 + count_at..4 + count_at + 4], &4u32.to_le_bytes(), "frame_id {n} chars");
        assert_eq!(b.len(), 4 + count_at + 4 + 4);
        let m = AudioDataStamped::decode(&b).unwrap();
        assert_eq!((m.header.frame_id.as_str(), m.samples().unwrap()), (id.as_str(), vec![7]));
    }
}

#[test]
fn chunk_info_round_trips_with_u64_fields_aligned_to_8() {
    for n in 0..=8usize {
        let m = ChunkInfo {
            header: header(&"f".repeat(n)),
            epoch: 3,
            first_frame: (1 << 40) + 1,
            frames: 480,
            chunk_first_frame: (1 << 40) + 1,
            chunk_frames: 480,
            flags: 1 | 8,
            monotonic_ns: u64::MAX - 1,
            realtime_ns: 1_700_000_000_000_000_001,
            lost_before: 960,
            bound_ns: 1000 * n as u64,
            missing_channels: 1 << n,
            unaligned_channels: u64::MAX - n as u64,
        };
        let mut b = Vec::new();
        m.encode(&mut b);
        // The three fields added last: the message's last 24 bytes.
        let tail: Vec<u8> = [m.bound_ns, m.missing_channels, m.unaligned_channels]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        assert_eq!(&b[b.len() - 24..], &tail[..], "frame_id {n} chars");
        // epoch: the first u64 after the string ending at 12 + n + 1.
        let epoch_at = (12 + n + 1).next_multiple_of(8);
        assert_eq!(&b[4 + epoch_at..4 + epoch_at + 8], &3u64.to_le_bytes(), "frame_id {n} chars");
        assert_eq!(ChunkInfo::decode(&b).unwrap(), m);
    }
}

#[test]
fn a_chunk_info_without_the_bound_reads_as_unknown_and_no_channel() {
    // The bytes of a ChunkInfo as bass wrote it before port format 2.4: every field up to
    // lost_before, laid out by hand.
    let mut b = CDR_LE.to_vec();
    b.extend_from_slice(&1_700_000_123i32.to_le_bytes());
    b.extend_from_slice(&456_789u32.to_le_bytes());
    b.extend_from_slice(&1u32.to_le_bytes());
    b.extend_from_slice(&[0, 0, 0, 0]); // "" + NUL, padding to 16
    for v in [3u64, 101] {
        b.extend_from_slice(&v.to_le_bytes()); // epoch, first_frame
    }
    b.extend_from_slice(&[100, 0, 0, 0, 0, 0, 0, 0]); // frames, padding
    b.extend_from_slice(&101u64.to_le_bytes()); // chunk_first_frame
    b.extend_from_slice(&100u32.to_le_bytes()); // chunk_frames
    b.extend_from_slice(&4u32.to_le_bytes()); // flags
    for v in [11u64, 12, 13] {
        b.extend_from_slice(&v.to_le_bytes()); // monotonic_ns, realtime_ns, lost_before
    }
    let m = ChunkInfo::decode(&b).unwrap();
    assert_eq!((m.first_frame, m.flags, m.monotonic_ns, m.lost_before), (101, 4, 11, 13));
    assert_eq!((m.bound_ns, m.missing_channels, m.unaligned_channels), (BOUND_UNKNOWN, 0, 0));
    // The new encoder writes exactly those bytes, then the three fields.
    let mut new = Vec::new();
    ChunkInfo { bound_ns: 5, missing_channels: 6, unaligned_channels: 7, ..m.clone() }.encode(&mut new);
    assert_eq!(&new[..b.len()], &b[..]);
    assert_eq!(new.len(), b.len() + 24);
}

#[test]
fn audio_info_round_trips_and_pads_after_the_u8() {
    let m = AudioInfo::s32le(2, 48_000);
    assert_eq!(m.bitrate, 48_000 * 2 * 32);
    let mut b = Vec::new();
    m.encode(&mut b);
    assert_eq!(&b[4..12], &[2, 0, 0, 0, 0x80, 0xbb, 0, 0]);
    assert_eq!(AudioInfo::decode(&b).unwrap(), m);
}

#[test]
fn every_truncation_and_bad_value_is_refused_by_name() {
    let mut b = Vec::new();
    let m = ChunkInfo {
        header: header("abc"),
        frames: 10,
        bound_ns: 7,
        missing_channels: 2,
        ..Default::default()
    };
    m.encode(&mut b);
    // A message cut right after lost_before (or in the 7 bytes after it) is one written before
    // the bound was added; a cut anywhere else is refused.
    let old = b.len() - 24;
    for cut in 0..b.len() {
        match ChunkInfo::decode(&b[..cut]) {
            Ok(o) => assert!((old..old + 8).contains(&cut), "cut at {cut} accepted: {o:?}"),
            Err(e) => assert!(!(old..old + 8).contains(&cut), "cut at {cut}: {e}"),
        }
    }
    let mut big = b.clone();
    big[4 + 8..4 + 12].copy_from_slice(&u32::MAX.to_le_bytes()); // frame_id length
    assert!(matches!(ChunkInfo::decode(&big), Err(CdrError::Truncated { field: "header.frame_id", .. })));
    let mut be = b.clone();
    be[1] = 0; // CDR_BE
    assert!(matches!(ChunkInfo::decode(&be), Err(CdrError::Encapsulation { .. })));
    let mut nsec = b.clone();
    nsec[8..12].copy_from_slice(&1_000_000_000u32.to_le_bytes());
    assert!(matches!(ChunkInfo::decode(&nsec), Err(CdrError::Range { field: "header.stamp.nanosec", .. })));
    let mut nonul = b.clone();
    nonul[4 + 12 + 3] = b'x';
    assert_eq!(ChunkInfo::decode(&nonul), Err(CdrError::BadString { field: "header.frame_id" }));
    let mut long = b.clone();
    long.extend_from_slice(&[0; 8]);
    assert_eq!(ChunkInfo::decode(&long), Err(CdrError::Trailing { extra: 8 }));
    let odd = AudioDataStamped { header: header(""), data: vec![1, 2, 3] };
    odd.encode(&mut b);
    assert!(AudioDataStamped::decode(&b).unwrap().samples().is_err());
}

#[test]
fn definitions_name_each_dependency_once_in_rosbag2_form() {
    for (def, deps) in [
        (
            AUDIO_DATA_STAMPED_DEFINITION,
            &["audio_common_msgs/AudioData", "std_msgs/Header", "builtin_interfaces/Time"][..],
        ),
        (CHUNK_INFO_DEFINITION, &["std_msgs/Header", "builtin_interfaces/Time"][..]),
        (AUDIO_INFO_DEFINITION, &[][..]),
    ] {
        let parts: Vec<&str> = def.split(&format!("\n{RULE}\n")).collect();
        assert_eq!(parts.len(), deps.len() + 1);
        for (p, d) in parts[1..].iter().zip(deps) {
            assert!(p.starts_with(&format!("MSG: {d}\n")), "{p:?}");
        }
        assert!(def.contains(&delimiter(deps.first().copied().unwrap_or("none"))) || deps.is_empty());
    }
}

#[test]
fn times_and_names_convert() {
    assert_eq!(Time::from_ns(1_500_000_001), Time { sec: 1, nanosec: 500_000_001 });
    assert_eq!(Time::from_ns(1_500_000_001).to_ns(), Some(1_500_000_001));
    assert_eq!(Time::from_ns(u64::MAX).sec, i32::MAX);
    assert_eq!(Time { sec: -1, nanosec: 0 }.to_ns(), None);
    assert_eq!(name_token("default"), "default");
    assert_eq!(name_token("left-ear.2"), "left_ear_2");
    assert_eq!(name_token("7mics"), "b7mics");
    assert_eq!(name_token("a--b"), "a_b");
    assert_eq!(Topics::of("default").audio, "/bass/default/audio");
    assert_eq!(Topics::of("x").chunks, "/bass/x/chunk_info");
}
