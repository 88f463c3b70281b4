//! The wire format: offsets, planar samples, batches, the flag mapping both ways, and
//! property tests that reach the decoder's every check (magic and version kept in step).

use super::*;
use proptest::prelude::*;

fn sample_header() -> Header {
    Header {
        magic: MAGIC,
        version: VERSION,
        header_len: HEADER_LEN as u16,
        flags: flags::SOURCE_LOSS,
        instance: 0xdead_beef,
        epoch: 3,
        sequence: 17,
        first_frame: 64 * 5 + 1,
        frames: 64,
        channels: 2,
        sample_format: SAMPLE_FORMAT_S32,
        sample_rate: 48000,
        chunks_on_port: 16,
        mono_ns: 1,
        realtime_ns: 2,
        send_mono_ns: 3,
        source_lost: 128,
        bound_ns: 40_000,
        missing_channels: 0b10,
        unaligned_channels: 0b01,
    }
}

fn batch_of(chunks: &[(Header, Vec<i32>)]) -> Vec<u8> {
    let mut b = Batch::new(chunks.len() as u32);
    for (h, s) in chunks {
        b.push(h, s);
    }
    b.take().unwrap().bytes
}

#[test]
fn a_chunk_round_trips_and_its_bytes_sit_at_the_documented_offsets() {
    let h = sample_header();
    let samples: Vec<i32> = (0..128).map(|i| i * 1000 - 7).collect();
    let bytes = encode(&h, &samples);
    assert_eq!(bytes.len(), 120 + 512);
    assert_eq!(&bytes[0..8], b"BASSNET\0");
    assert_eq!(u16::from_le_bytes(bytes[8..10].try_into().unwrap()), 2);
    assert_eq!(u64::from_le_bytes(bytes[40..48].try_into().unwrap()), 321);
    assert_eq!(u64::from_le_bytes(bytes[96..104].try_into().unwrap()), 40_000);
    assert_eq!(u64::from_le_bytes(bytes[104..112].try_into().unwrap()), 0b10);
    // Planar: channel 0's 64 frames, then channel 1's.
    assert_eq!(i32::from_le_bytes(bytes[120..124].try_into().unwrap()), -7);
    assert_eq!(i32::from_le_bytes(bytes[120 + 256..124 + 256].try_into().unwrap()), 64 * 1000 - 7);
    let c = decode(&bytes).unwrap();
    assert_eq!(c.header, h);
    assert_eq!(c.planar(), samples);
    // Decoded from an odd address too (received bytes need not be aligned).
    let mut shifted = vec![0u8];
    shifted.extend(&bytes);
    assert_eq!(decode(&shifted[1..]).unwrap().planar(), samples);
}

/// A message of a serve from before the bound (its header 96 bytes, samples right after) is
/// read: no bound, no masks; batched with new ones too.
#[test]
fn a_96_byte_header_of_before_the_bound_decodes_with_no_bound_and_no_masks() {
    let h = sample_header();
    let samples: Vec<i32> = (0..128).collect();
    let new = encode(&h, &samples);
    let mut old = new[..96].to_vec();
    old[10..12].copy_from_slice(&96u16.to_le_bytes());
    old.extend_from_slice(&new[120..]);
    let c = decode(&old).unwrap();
    assert_eq!((c.header.bound_ns, c.header.missing_channels, c.header.unaligned_channels), (u64::MAX, 0, 0));
    assert_eq!((c.header.first_frame, c.planar()), (321, samples));
    let both: Vec<u8> = old.iter().chain(new.iter()).copied().collect();
    let got: Vec<u64> = decode_batch(&both).unwrap().map(|c| c.header.bound_ns).collect();
    assert_eq!(got, [u64::MAX, 40_000]);
    let mut short = old.clone();
    short[10..12].copy_from_slice(&95u16.to_le_bytes());
    assert_eq!(decode(&short), Err(DecodeError::Field { field: "header_len", value: 95 }));
}

/// A channel mask with a bit past the chunk's channels is refused, naming the mask.
#[test]
fn a_channel_mask_naming_a_channel_the_chunk_lacks_is_refused() {
    let samples = vec![0; 128];
    let h = Header { missing_channels: 0b100, ..sample_header() };
    assert_eq!(
        decode(&encode(&h, &samples)),
        Err(DecodeError::Field { field: "missing_channels", value: 4 })
    );
    let h = Header { unaligned_channels: 1 << 63, ..sample_header() };
    assert_eq!(
        decode(&encode(&h, &samples)),
        Err(DecodeError::Field { field: "unaligned_channels", value: 1 << 63 })
    );
    let h = Header { channels: 64, missing_channels: u64::MAX, ..sample_header() };
    assert!(decode(&encode(&h, &vec![0; 64 * 64])).is_ok());
}

#[test]
fn a_gap_chunk_carries_no_samples_and_a_wrong_payload_is_refused() {
    let h = Header { flags: flags::GAP, ..sample_header() };
    let gap = encode(&h, &[]);
    assert!(decode(&gap).unwrap().is_gap());
    assert_eq!(decode(&gap).unwrap().planar(), Vec::<i32>::new());
    let data = sample_header();
    assert_eq!(decode(&encode(&data, &[1, 2])), Err(DecodeError::Payload { found: 8, expected: 512 }));
}

#[test]
fn a_batch_decodes_chunk_by_chunk_and_a_truncated_batch_is_refused_whole() {
    let samples: Vec<i32> = (0..128).collect();
    let mut parts: Vec<(Header, Vec<i32>)> = (0..3u64)
        .map(|k| (Header { sequence: 7 + k, first_frame: 321 + 64 * k, ..sample_header() }, samples.clone()))
        .collect();
    // A GAP chunk (no samples) in the middle of a batch too.
    let gap = Header { flags: flags::GAP, sequence: 10, first_frame: 321 + 64 * 3, ..sample_header() };
    parts.push((gap, vec![]));
    let batch = batch_of(&parts);
    let mut b = Batch::new(4);
    assert!(!b.push(&parts[0].0, &parts[0].1), "not full after one of four");
    let chunks: Vec<Chunk> = decode_batch(&batch).unwrap().collect();
    let firsts: Vec<u64> = chunks.iter().map(|c| c.header.first_frame).collect();
    assert_eq!(firsts, vec![321, 385, 449, 513]);
    assert_eq!(chunks[2].planar(), samples);
    assert!(chunks[3].is_gap() && chunks[3].sample_bytes.is_empty());
    assert_eq!(decode_batch(&batch).unwrap().len(), 4);
    // One message is a batch of one.
    assert_eq!(decode_batch(&encode(&sample_header(), &samples)).unwrap().count(), 1);
    // Cut inside the second chunk: nothing of the message is taken.
    assert!(matches!(decode_batch(&batch[..HEADER_LEN + 512 + 100]), Err(DecodeError::Payload { .. })));
    assert_eq!(decode_batch(&[]).unwrap_err(), DecodeError::Short(0));
    // A full batch is taken once, with its counts.
    let mut b = Batch::new(2);
    assert!(!b.push(&parts[0].0, &samples) && b.push(&parts[1].0, &samples));
    let t = b.take().unwrap();
    assert_eq!((t.first_sequence, t.chunks, t.frames, t.bytes.len()), (7, 2, 128, 2 * (HEADER_LEN + 512)));
    assert!(b.take().is_none());
}

#[test]
fn a_version_1_message_is_refused_naming_both_versions() {
    let mut b = encode(&sample_header(), &[0; 128]);
    b[8] = 1;
    let e = decode(&b).unwrap_err();
    assert_eq!(e, DecodeError::Version { found: 1 });
    let text = e.to_string();
    assert!(text.contains("wire version 1") && text.contains("version 2"), "{text}");
    assert!(decode_batch(&b).is_err());
    let h = Header { first_frame: 2, ..sample_header() };
    assert_eq!(decode(&encode(&h, &[0; 128])), Err(DecodeError::Field { field: "first_frame", value: 2 }));
}

#[test]
fn the_flags_are_the_ports_bit_for_bit_and_source_loss_has_a_bit_of_its_own() {
    use bassport::format::chunk_flags as cf;
    assert_eq!(
        (flags::GAP, flags::DISCONTINUITY, flags::TIME_ESTIMATED, flags::LATE),
        (cf::GAP, cf::DISCONTINUITY, cf::TIME_ESTIMATED, cf::LATE)
    );
    for port in 0..16u32 {
        let w = flags_of_port(port, false);
        assert_eq!(w, port, "port flags {port:#x} travel as they are");
        assert_eq!(port_flags(w), port, "and come back as they were");
        let lost = flags_of_port(port, true);
        assert_eq!(lost, port | flags::SOURCE_LOSS);
        assert_eq!(port_flags(lost), port | cf::DISCONTINUITY, "a loss before: a discontinuity");
    }
    // A port flag this version does not know is not put on the wire; a message with an
    // unknown bit is refused.
    assert_eq!(flags_of_port(1 << 9 | cf::LATE, false), cf::LATE);
    let h = Header { flags: 1 << 5, ..sample_header() };
    assert_eq!(decode(&encode(&h, &[0; 128])), Err(DecodeError::Field { field: "flags", value: 32 }));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, ..ProptestConfig::default() })]

    /// Any mutation of a valid message decodes to a named error or to a message whose
    /// fields are within range and whose samples match frames x channels.
    #[test]
    fn mutated_messages_never_panic_and_decode_only_to_valid_chunks(
        muts in proptest::collection::vec((0usize..700, any::<u8>()), 1..16),
        cut in proptest::option::of(0usize..700),
    ) {
        let mut b = encode(&sample_header(), &[5; 128]);
        for (at, v) in muts { if at < b.len() { b[at] = v; } }
        if let Some(c) = cut { b.truncate(c); }
        if let Ok(c) = decode(&b) {
            let h = c.header;
            prop_assert!(h.frames >= 1 && h.frames <= MAX_FRAMES);
            prop_assert!(h.channels >= 1 && h.channels <= MAX_CHANNELS);
            prop_assert!(h.first_frame >= 1 && (h.first_frame - 1) % u64::from(h.frames) == 0);
            prop_assert_eq!(h.flags & !flags::ALL, 0);
            let n = if h.flags & flags::GAP != 0 { 0 } else { h.frames as usize * h.channels as usize };
            prop_assert_eq!(c.planar().len(), n);
        }
        if let Ok(chunks) = decode_batch(&b) {
            prop_assert_eq!(chunks.count(), 1);
        }
    }

    #[test]
    fn random_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = decode(&b);
        let _ = decode_batch(&b).map(|c| c.count());
    }

    #[test]
    fn any_valid_header_round_trips_alone_and_in_a_batch(
        flags in 0u32..32, instance in any::<u64>(), epoch in 1u64..u64::MAX, seq in any::<u64>(),
        chunk in 0u64..1_000_000, frames in 1u32..300, channels in 1u16..=8, rate in 1u32..400_000,
        per_message in 1usize..5,
    ) {
        let h = Header { flags, instance, epoch, sequence: seq, first_frame: chunk * u64::from(frames) + 1,
            frames, channels, sample_rate: rate, missing_channels: 1 << (channels - 1), unaligned_channels: 1,
            ..sample_header() };
        let n = if flags & flags::GAP != 0 { 0 } else { frames as usize * channels as usize };
        let samples: Vec<i32> = (0..n as i32).map(|i| i.wrapping_mul(-7_654_321)).collect();
        let bytes = encode(&h, &samples);
        let c = decode(&bytes).unwrap();
        prop_assert_eq!(c.header, h);
        prop_assert_eq!(c.planar(), samples.clone());
        let batch = batch_of(&vec![(h, samples.clone()); per_message]);
        let got: Vec<Chunk> = decode_batch(&batch).unwrap().collect();
        prop_assert_eq!(got.len(), per_message);
        for c in got {
            prop_assert_eq!(c.header, h);
            prop_assert_eq!(c.planar(), samples.clone());
        }
    }
}
