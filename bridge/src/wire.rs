//! The network chunk message, version 1: the one definition of what `serve` puts on Zenoh
//! and `mirror` takes off it. One message carries one source chunk.
//!
//! ```text
//!  offset  size  field            (all integers little-endian)
//!  0       8     magic            b"BASSNET\0"
//!  8       2     version          1 (a decoder refuses any other)
//!  10      2     header_len       96; samples start here (a later version may grow it)
//!  12      4     flags            GAP | SOURCE_LOSS | DISCONTINUITY | TIME_ESTIMATED
//!  16      8     instance         random id of the sending `serve` process
//!  24      8     epoch            the source port's acquisition epoch
//!  32      8     sequence         chunks read by this instance, from 0, +1 per chunk,
//!                                 dropped ones included (a jump = chunks not sent)
//!  40      8     first_frame      index of the chunk's first frame (>= 1)
//!  48      4     frames           frames in the chunk (the source's nFramesPerChunk)
//!  52      2     channels         1..=64
//!  54      2     sample_format    1 = S32
//!  56      4     sample_rate      Hz
//!  60      4     chunks_on_port   the source port's nChunksOnPort
//!  64      8     mono_ns          source CLOCK_MONOTONIC of the first frame
//!  72      8     realtime_ns      source CLOCK_REALTIME of the first frame
//!  80      8     send_mono_ns     source CLOCK_MONOTONIC when the message was queued
//!  88      8     source_lost      frames this instance could not send so far (cumulative)
//!  96      4*frames*channels      samples, frame-interleaved i32; empty when GAP is set
//! ```
//!
//! The layout is the [`Header`] struct (`repr(C)`, no padding); the offsets above are
//! asserted at compile time against it. [`decode`] validates every field before a value is
//! used. docs/network.md shows the same diagram.

use std::mem::{offset_of, size_of};

/// `b"BASSNET\0"`.
pub const MAGIC: [u8; 8] = *b"BASSNET\0";
/// Wire format version.
pub const VERSION: u16 = 1;
/// Bytes of the version-1 header.
pub const HEADER_LEN: usize = 96;
/// Sample format code: signed 32-bit.
pub const SAMPLE_FORMAT_S32: u16 = 1;
/// Most frames a chunk may carry (a larger value is a corrupt or hostile message).
pub const MAX_FRAMES: u32 = 1 << 20;
/// Most channels.
pub const MAX_CHANNELS: u16 = 64;

/// Message flags.
pub mod flags {
    /// Zero-filled frames (a device gap at the source); no samples follow.
    pub const GAP: u32 = 1;
    /// Chunks before this one were read but not sent (bridge queue full or reader lapped).
    pub const SOURCE_LOSS: u32 = 2;
    /// The source marked this chunk as the first after an overrun.
    pub const DISCONTINUITY: u32 = 4;
    /// The source's timestamps are estimated.
    pub const TIME_ESTIMATED: u32 = 8;
}

/// The fixed header, in wire order.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Header {
    /// [`MAGIC`].
    pub magic: [u8; 8],
    /// [`VERSION`].
    pub version: u16,
    /// [`HEADER_LEN`] (or more in a later version).
    pub header_len: u16,
    /// [`flags`].
    pub flags: u32,
    /// Sending instance.
    pub instance: u64,
    /// Source acquisition epoch.
    pub epoch: u64,
    /// Chunk sequence number of this instance.
    pub sequence: u64,
    /// First frame index.
    pub first_frame: u64,
    /// Frames.
    pub frames: u32,
    /// Channels.
    pub channels: u16,
    /// [`SAMPLE_FORMAT_S32`].
    pub sample_format: u16,
    /// Hz.
    pub sample_rate: u32,
    /// Source nChunksOnPort.
    pub chunks_on_port: u32,
    /// Source CLOCK_MONOTONIC of the first frame.
    pub mono_ns: u64,
    /// Source CLOCK_REALTIME of the first frame.
    pub realtime_ns: u64,
    /// Source CLOCK_MONOTONIC at send.
    pub send_mono_ns: u64,
    /// Frames this instance could not send so far.
    pub source_lost: u64,
}

const _: () = assert!(size_of::<Header>() == HEADER_LEN);
const _: () = assert!(offset_of!(Header, version) == 8);
const _: () = assert!(offset_of!(Header, header_len) == 10);
const _: () = assert!(offset_of!(Header, flags) == 12);
const _: () = assert!(offset_of!(Header, instance) == 16);
const _: () = assert!(offset_of!(Header, epoch) == 24);
const _: () = assert!(offset_of!(Header, sequence) == 32);
const _: () = assert!(offset_of!(Header, first_frame) == 40);
const _: () = assert!(offset_of!(Header, frames) == 48);
const _: () = assert!(offset_of!(Header, channels) == 52);
const _: () = assert!(offset_of!(Header, sample_format) == 54);
const _: () = assert!(offset_of!(Header, sample_rate) == 56);
const _: () = assert!(offset_of!(Header, chunks_on_port) == 60);
const _: () = assert!(offset_of!(Header, mono_ns) == 64);
const _: () = assert!(offset_of!(Header, realtime_ns) == 72);
const _: () = assert!(offset_of!(Header, send_mono_ns) == 80);
const _: () = assert!(offset_of!(Header, source_lost) == 88);

/// Why a message was refused.
#[derive(Debug, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Shorter than a header.
    #[error("message of {0} bytes is shorter than the {HEADER_LEN}-byte header")]
    Short(usize),
    /// Not a bass chunk message.
    #[error("bad magic {0:02x?}")]
    Magic([u8; 8]),
    /// Another wire version.
    #[error("wire version {found}, this bridge speaks {VERSION}")]
    Version {
        /// Version found.
        found: u16,
    },
    /// A field out of range; names the field and its value.
    #[error("invalid {field} = {value}")]
    Field {
        /// Field name.
        field: &'static str,
        /// Value found.
        value: u64,
    },
    /// The payload does not match frames x channels.
    #[error("{found} sample bytes, expected {expected}")]
    Payload {
        /// Bytes found.
        found: usize,
        /// Bytes expected.
        expected: usize,
    },
}

/// A decoded, validated message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Chunk {
    /// The header.
    pub header: Header,
    /// Interleaved samples, `frames * channels` of them; empty for a GAP chunk.
    pub samples: Vec<i32>,
}

fn put<const N: usize>(out: &mut [u8], at: usize, bytes: [u8; N]) {
    out[at..at + N].copy_from_slice(&bytes);
}

fn get<const N: usize>(b: &[u8], at: usize) -> [u8; N] {
    let mut a = [0u8; N];
    a.copy_from_slice(&b[at..at + N]);
    a
}

/// Encodes a header and its samples (empty for GAP) into one message.
pub fn encode(h: &Header, samples: &[i32]) -> Vec<u8> {
    let mut out = vec![0u8; HEADER_LEN + samples.len() * 4];
    put(&mut out, offset_of!(Header, magic), MAGIC);
    put(&mut out, offset_of!(Header, version), VERSION.to_le_bytes());
    put(&mut out, offset_of!(Header, header_len), (HEADER_LEN as u16).to_le_bytes());
    put(&mut out, offset_of!(Header, flags), h.flags.to_le_bytes());
    put(&mut out, offset_of!(Header, instance), h.instance.to_le_bytes());
    put(&mut out, offset_of!(Header, epoch), h.epoch.to_le_bytes());
    put(&mut out, offset_of!(Header, sequence), h.sequence.to_le_bytes());
    put(&mut out, offset_of!(Header, first_frame), h.first_frame.to_le_bytes());
    put(&mut out, offset_of!(Header, frames), h.frames.to_le_bytes());
    put(&mut out, offset_of!(Header, channels), h.channels.to_le_bytes());
    put(&mut out, offset_of!(Header, sample_format), SAMPLE_FORMAT_S32.to_le_bytes());
    put(&mut out, offset_of!(Header, sample_rate), h.sample_rate.to_le_bytes());
    put(&mut out, offset_of!(Header, chunks_on_port), h.chunks_on_port.to_le_bytes());
    put(&mut out, offset_of!(Header, mono_ns), h.mono_ns.to_le_bytes());
    put(&mut out, offset_of!(Header, realtime_ns), h.realtime_ns.to_le_bytes());
    put(&mut out, offset_of!(Header, send_mono_ns), h.send_mono_ns.to_le_bytes());
    put(&mut out, offset_of!(Header, source_lost), h.source_lost.to_le_bytes());
    for (d, s) in out[HEADER_LEN..].chunks_exact_mut(4).zip(samples) {
        d.copy_from_slice(&s.to_le_bytes());
    }
    out
}

/// Decodes and validates one message. Never panics, whatever the bytes.
pub fn decode(b: &[u8]) -> Result<Chunk, DecodeError> {
    if b.len() < HEADER_LEN {
        return Err(DecodeError::Short(b.len()));
    }
    let magic: [u8; 8] = get(b, 0);
    if magic != MAGIC {
        return Err(DecodeError::Magic(magic));
    }
    let u16_at = |o| u16::from_le_bytes(get(b, o));
    let u32_at = |o| u32::from_le_bytes(get(b, o));
    let u64_at = |o| u64::from_le_bytes(get(b, o));
    let version = u16_at(offset_of!(Header, version));
    if version != VERSION {
        return Err(DecodeError::Version { found: version });
    }
    let h = Header {
        magic,
        version,
        header_len: u16_at(offset_of!(Header, header_len)),
        flags: u32_at(offset_of!(Header, flags)),
        instance: u64_at(offset_of!(Header, instance)),
        epoch: u64_at(offset_of!(Header, epoch)),
        sequence: u64_at(offset_of!(Header, sequence)),
        first_frame: u64_at(offset_of!(Header, first_frame)),
        frames: u32_at(offset_of!(Header, frames)),
        channels: u16_at(offset_of!(Header, channels)),
        sample_format: u16_at(offset_of!(Header, sample_format)),
        sample_rate: u32_at(offset_of!(Header, sample_rate)),
        chunks_on_port: u32_at(offset_of!(Header, chunks_on_port)),
        mono_ns: u64_at(offset_of!(Header, mono_ns)),
        realtime_ns: u64_at(offset_of!(Header, realtime_ns)),
        send_mono_ns: u64_at(offset_of!(Header, send_mono_ns)),
        source_lost: u64_at(offset_of!(Header, source_lost)),
    };
    let field = |field, value: u64| Err(DecodeError::Field { field, value });
    let hl = usize::from(h.header_len);
    if hl < HEADER_LEN || hl > b.len() {
        return field("header_len", hl as u64);
    }
    if h.frames == 0 || h.frames > MAX_FRAMES {
        return field("frames", h.frames.into());
    }
    if h.channels == 0 || h.channels > MAX_CHANNELS {
        return field("channels", h.channels.into());
    }
    if h.sample_format != SAMPLE_FORMAT_S32 {
        return field("sample_format", h.sample_format.into());
    }
    if h.sample_rate == 0 {
        return field("sample_rate", 0);
    }
    if h.chunks_on_port == 0 || u64::from(h.chunks_on_port) * u64::from(h.frames) > u64::from(u32::MAX) {
        return field("chunks_on_port", h.chunks_on_port.into());
    }
    if h.epoch == 0 {
        return field("epoch", 0);
    }
    // Frames are numbered from 1 and a source chunk starts at a multiple of its size plus 1.
    let max_frame = bassclient::format::MAX_FRAME_INDEX;
    if h.first_frame == 0
        || h.first_frame > max_frame - u64::from(h.frames)
        || (h.first_frame - 1) % u64::from(h.frames) != 0
    {
        return field("first_frame", h.first_frame);
    }
    let payload = &b[hl..];
    let expected =
        if h.flags & flags::GAP != 0 { 0 } else { h.frames as usize * usize::from(h.channels) * 4 };
    if payload.len() != expected {
        return Err(DecodeError::Payload { found: payload.len(), expected });
    }
    let samples = payload.chunks_exact(4).map(|s| i32::from_le_bytes(get(s, 0))).collect();
    Ok(Chunk { header: h, samples })
}

/// Decodes a message of one or more chunk messages laid end to end (`serve
/// --chunks-per-message N` sends N in one Zenoh message; N = 1 is a plain message). Each is
/// validated as by [`decode`]; a truncated or malformed part refuses the whole message.
pub fn decode_batch(b: &[u8]) -> Result<Vec<Chunk>, DecodeError> {
    let mut out = Vec::new();
    let mut rest = b;
    while !rest.is_empty() {
        let len = message_len(rest)?;
        out.push(decode(&rest[..len])?);
        rest = &rest[len..];
    }
    if out.is_empty() {
        return Err(DecodeError::Short(0));
    }
    Ok(out)
}

/// The length of the chunk message at the start of `b`, from its header (header length,
/// frames, channels, GAP), checked against what `b` holds.
fn message_len(b: &[u8]) -> Result<usize, DecodeError> {
    if b.len() < HEADER_LEN {
        return Err(DecodeError::Short(b.len()));
    }
    let hl = usize::from(u16::from_le_bytes(get(b, offset_of!(Header, header_len))));
    let fl = u32::from_le_bytes(get(b, offset_of!(Header, flags)));
    let frames = u32::from_le_bytes(get(b, offset_of!(Header, frames)));
    let channels = u16::from_le_bytes(get(b, offset_of!(Header, channels)));
    // Out-of-range values are named by decode; here they only must not overflow.
    let payload = if fl & flags::GAP != 0 {
        0
    } else {
        frames.min(MAX_FRAMES) as usize * usize::from(channels.min(MAX_CHANNELS)) * 4
    };
    let len = hl.max(HEADER_LEN) + payload;
    if len > b.len() {
        return Err(DecodeError::Payload { found: b.len().saturating_sub(hl), expected: payload });
    }
    Ok(len)
}

#[cfg(test)]
mod tests {
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
        }
    }

    #[test]
    fn a_chunk_round_trips_and_its_bytes_sit_at_the_documented_offsets() {
        let h = sample_header();
        let samples: Vec<i32> = (0..128).map(|i| i * 1000 - 7).collect();
        let bytes = encode(&h, &samples);
        assert_eq!(bytes.len(), 96 + 512);
        assert_eq!(&bytes[0..8], b"BASSNET\0");
        assert_eq!(u64::from_le_bytes(bytes[40..48].try_into().unwrap()), 321);
        assert_eq!(i32::from_le_bytes(bytes[96..100].try_into().unwrap()), -7);
        let c = decode(&bytes).unwrap();
        assert_eq!(c.header, h);
        assert_eq!(c.samples, samples);
    }

    #[test]
    fn a_gap_chunk_carries_no_samples_and_a_wrong_payload_is_refused() {
        let h = Header { flags: flags::GAP, ..sample_header() };
        assert_eq!(decode(&encode(&h, &[])).unwrap().samples, Vec::<i32>::new());
        let data = sample_header();
        assert_eq!(decode(&encode(&data, &[1, 2])), Err(DecodeError::Payload { found: 8, expected: 512 }));
    }

    #[test]
    fn a_batch_decodes_chunk_by_chunk_and_a_truncated_batch_is_refused_whole() {
        let samples: Vec<i32> = (0..128).collect();
        let mut batch = Vec::new();
        for k in 0..3u64 {
            let h = Header { sequence: 7 + k, first_frame: 321 + 64 * k, ..sample_header() };
            batch.extend(encode(&h, &samples));
        }
        // A GAP chunk (no samples) in the middle of a batch too.
        let gap = Header { flags: flags::GAP, sequence: 10, first_frame: 321 + 64 * 3, ..sample_header() };
        batch.extend(encode(&gap, &[]));
        let chunks = decode_batch(&batch).unwrap();
        let firsts: Vec<u64> = chunks.iter().map(|c| c.header.first_frame).collect();
        assert_eq!(firsts, vec![321, 385, 449, 513]);
        assert_eq!(chunks[2].samples, samples);
        assert!(chunks[3].samples.is_empty());
        // One message is a batch of one.
        assert_eq!(decode_batch(&encode(&sample_header(), &samples)).unwrap().len(), 1);
        // Cut inside the second chunk: nothing of the message is taken.
        assert!(matches!(decode_batch(&batch[..96 + 512 + 100]), Err(DecodeError::Payload { .. })));
        assert_eq!(decode_batch(&[]), Err(DecodeError::Short(0)));
    }

    #[test]
    fn another_version_and_a_chunk_that_does_not_start_a_chunk_are_named_errors() {
        let mut b = encode(&sample_header(), &[0; 128]);
        b[8] = 2;
        assert_eq!(decode(&b), Err(DecodeError::Version { found: 2 }));
        let h = Header { first_frame: 2, ..sample_header() };
        assert_eq!(
            decode(&encode(&h, &[0; 128])),
            Err(DecodeError::Field { field: "first_frame", value: 2 })
        );
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
                let n = if h.flags & flags::GAP != 0 { 0 } else { h.frames as usize * h.channels as usize };
                prop_assert_eq!(c.samples.len(), n);
            }
        }

        #[test]
        fn random_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..400)) {
            let _ = decode(&b);
        }

        #[test]
        fn any_valid_header_round_trips(
            flags in 0u32..16, instance in any::<u64>(), epoch in 1u64..u64::MAX, seq in any::<u64>(),
            chunk in 0u64..1_000_000, frames in 1u32..300, channels in 1u16..=8, rate in 1u32..400_000,
        ) {
            let h = Header { flags, instance, epoch, sequence: seq, first_frame: chunk * u64::from(frames) + 1,
                frames, channels, sample_rate: rate, ..sample_header() };
            let n = if flags & flags::GAP != 0 { 0 } else { frames as usize * channels as usize };
            let samples: Vec<i32> = (0..n as i32).collect();
            let c = decode(&encode(&h, &samples)).unwrap();
            prop_assert_eq!(c.header, h);
            prop_assert_eq!(c.samples, samples);
        }
    }
}
