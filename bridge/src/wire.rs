//! The network chunk message, version 2: the one definition of what `serve` puts on Zenoh
//! and `mirror` takes off it. One message carries one source chunk; a Zenoh message carries
//! one or more of them laid end to end ([`Batch`], [`decode_batch`]).
//!
//! ```text
//!  offset  size  field            (all integers little-endian)
//!  0       8     magic            b"BASSNET\0"
//!  8       2     version          2 (a decoder refuses any other)
//!  10      2     header_len       120; samples start here (96 before 2026-12-03, without
//!                                 the three fields at 96..120; a later version may grow it)
//!  12      4     flags            the port's chunk flags, same bits (GAP 1, DISCONTINUITY 2,
//!                                 TIME_ESTIMATED 4, LATE 8), and the bridge's SOURCE_LOSS 16
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
//!  96      8     bound_ns         the source chunk's timestamp bound (port format 2.4);
//!                                 u64::MAX = not known (and for a 96-byte header)
//!  104     8     missing_channels the source chunk's channels not real (bit c: channel c)
//!  112     8     unaligned_channels the source chunk's channels not yet aligned
//!  120     4*frames*channels      samples, planar i32: channel 0's frames, then channel
//!                                 1's, ... (the port's own layout); empty when GAP is set
//! ```
//!
//! Version 1 (until 2026-12) numbered the flags differently (SOURCE_LOSS 2, DISCONTINUITY 4,
//! TIME_ESTIMATED 8, no LATE) and interleaved the samples; it is refused by name.
//!
//! The layout is the [`Header`] struct (`repr(C)`, no padding); the offsets above are
//! asserted at compile time against it. [`decode`] validates every field before a value is
//! used and borrows the samples from the message ([`Chunk`]): no allocation per chunk.
//! docs/network.md shows the same diagram.

use std::mem::{offset_of, size_of};

use bassport::format::chunk_flags;

/// `b"BASSNET\0"`.
pub const MAGIC: [u8; 8] = *b"BASSNET\0";
/// Wire format version.
pub const VERSION: u16 = 2;
/// Bytes of the header this version writes.
pub const HEADER_LEN: usize = 120;
/// Bytes of the shortest header a decoder accepts: the header of version 2 before the
/// timestamp bound and the channel masks (2026-12-03), which then read as unknown and empty.
pub const MIN_HEADER_LEN: usize = 96;
/// Sample format code: signed 32-bit.
pub const SAMPLE_FORMAT_S32: u16 = 1;
/// Most frames a chunk may carry (a larger value is a corrupt or hostile message).
pub const MAX_FRAMES: u32 = 1 << 20;
/// Most channels: the port format's.
pub const MAX_CHANNELS: u16 = {
    let m = bassport::format::MAX_CHANNELS;
    assert!(m <= u16::MAX as u32);
    m as u16
};

/// Message flags: the port's chunk flags with their own bits, then the bridge's.
pub mod flags {
    use super::chunk_flags;
    /// Zero-filled frames (a device gap at the source); no samples follow.
    pub const GAP: u32 = chunk_flags::GAP;
    /// The source marked this chunk as the first after an overrun.
    pub const DISCONTINUITY: u32 = chunk_flags::DISCONTINUITY;
    /// The source's timestamps are estimated.
    pub const TIME_ESTIMATED: u32 = chunk_flags::TIME_ESTIMATED;
    /// The source's capture delivered this chunk late, in a catch-up burst.
    pub const LATE: u32 = chunk_flags::LATE;
    /// Chunks before this one were read but not sent (bridge queue full or reader lapped).
    pub const SOURCE_LOSS: u32 = 16;
    /// The bits that are the port's chunk flags.
    pub const PORT: u32 = GAP | DISCONTINUITY | TIME_ESTIMATED | LATE;
    /// Every bit of this version; a message with another one set is refused.
    pub const ALL: u32 = PORT | SOURCE_LOSS;
}

const _: () = assert!(flags::SOURCE_LOSS & flags::PORT == 0 && flags::SOURCE_LOSS > flags::PORT);
const _: () = assert!(flags::ALL == 31);

/// The message flags of a source chunk: its port chunk flags, bit for bit, and
/// [`flags::SOURCE_LOSS`] when chunks before it were not sent.
pub fn flags_of_port(port_flags: u32, source_loss: bool) -> u32 {
    (port_flags & flags::PORT) | if source_loss { flags::SOURCE_LOSS } else { 0 }
}

/// The port chunk flags a message stands for (the other way): the source's, bit for bit,
/// with DISCONTINUITY added after a [`flags::SOURCE_LOSS`] (the chunks between were lost).
pub fn port_flags(wire_flags: u32) -> u32 {
    let mut f = wire_flags & flags::PORT;
    if wire_flags & flags::SOURCE_LOSS != 0 {
        f |= chunk_flags::DISCONTINUITY;
    }
    f
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
    /// The source chunk's timestamp bound (ns; `BOUND_UNKNOWN` = not known).
    pub bound_ns: u64,
    /// The source chunk's channels whose frames are not real (bit c: channel c).
    pub missing_channels: u64,
    /// The source chunk's channels not yet aligned (bit c: channel c).
    pub unaligned_channels: u64,
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
const _: () = assert!(offset_of!(Header, bound_ns) == 96);
const _: () = assert!(MIN_HEADER_LEN == 96);
const _: () = assert!(offset_of!(Header, missing_channels) == 104);
const _: () = assert!(offset_of!(Header, unaligned_channels) == 112);

/// Why a message was refused.
#[derive(Debug, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Shorter than a header.
    #[error("message of {0} bytes is shorter than the {MIN_HEADER_LEN}-byte header")]
    Short(usize),
    /// Not a bass chunk message.
    #[error("bad magic {0:02x?}")]
    Magic([u8; 8]),
    /// Another wire version.
    #[error("wire version {found}, this bridge speaks version {VERSION} (update serve and mirror together)")]
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

/// A decoded, validated message; its samples are borrowed from the message's bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Chunk<'a> {
    /// The header.
    pub header: Header,
    /// The samples as they lie on the wire: `frames * channels` little-endian i32, planar;
    /// empty for a GAP chunk. Not aligned: read with [`Chunk::planar_into`].
    pub sample_bytes: &'a [u8],
}

impl Chunk<'_> {
    /// Whether the chunk is a GAP (no samples).
    pub fn is_gap(&self) -> bool {
        self.header.flags & flags::GAP != 0
    }

    /// The samples into `out` (reused: resized to `frames * channels`, no allocation once it
    /// has grown): channel 0's frames, then channel 1's, ... Empty for a GAP chunk.
    pub fn planar_into(&self, out: &mut Vec<i32>) {
        out.clear();
        out.extend(self.sample_bytes.chunks_exact(4).map(|s| i32::from_le_bytes(get(s, 0))));
    }

    /// The samples, planar, in a new vector (tests and tools).
    pub fn planar(&self) -> Vec<i32> {
        let mut v = Vec::new();
        self.planar_into(&mut v);
        v
    }
}

fn put<const N: usize>(out: &mut [u8], at: usize, bytes: [u8; N]) {
    out[at..at + N].copy_from_slice(&bytes);
}

fn get<const N: usize>(b: &[u8], at: usize) -> [u8; N] {
    let mut a = [0u8; N];
    a.copy_from_slice(&b[at..at + N]);
    a
}

/// Appends one message to `out`: the header (`magic`, `version`, `header_len` and
/// `sample_format` are this version's whatever `h` says) and the samples, planar
/// (`frames * channels` of them, channel after channel; empty for GAP).
pub fn encode_into(out: &mut Vec<u8>, h: &Header, planar: &[i32]) {
    let at = out.len();
    out.resize(at + HEADER_LEN, 0);
    let head = &mut out[at..];
    put(head, offset_of!(Header, magic), MAGIC);
    put(head, offset_of!(Header, version), VERSION.to_le_bytes());
    put(head, offset_of!(Header, header_len), (HEADER_LEN as u16).to_le_bytes());
    put(head, offset_of!(Header, flags), h.flags.to_le_bytes());
    put(head, offset_of!(Header, instance), h.instance.to_le_bytes());
    put(head, offset_of!(Header, epoch), h.epoch.to_le_bytes());
    put(head, offset_of!(Header, sequence), h.sequence.to_le_bytes());
    put(head, offset_of!(Header, first_frame), h.first_frame.to_le_bytes());
    put(head, offset_of!(Header, frames), h.frames.to_le_bytes());
    put(head, offset_of!(Header, channels), h.channels.to_le_bytes());
    put(head, offset_of!(Header, sample_format), SAMPLE_FORMAT_S32.to_le_bytes());
    put(head, offset_of!(Header, sample_rate), h.sample_rate.to_le_bytes());
    put(head, offset_of!(Header, chunks_on_port), h.chunks_on_port.to_le_bytes());
    put(head, offset_of!(Header, mono_ns), h.mono_ns.to_le_bytes());
    put(head, offset_of!(Header, realtime_ns), h.realtime_ns.to_le_bytes());
    put(head, offset_of!(Header, send_mono_ns), h.send_mono_ns.to_le_bytes());
    put(head, offset_of!(Header, source_lost), h.source_lost.to_le_bytes());
    put(head, offset_of!(Header, bound_ns), h.bound_ns.to_le_bytes());
    put(head, offset_of!(Header, missing_channels), h.missing_channels.to_le_bytes());
    put(head, offset_of!(Header, unaligned_channels), h.unaligned_channels.to_le_bytes());
    out.reserve(planar.len() * 4);
    for s in planar {
        out.extend_from_slice(&s.to_le_bytes());
    }
}

/// One message in a new buffer (see [`encode_into`]).
pub fn encode(h: &Header, planar: &[i32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + planar.len() * 4);
    encode_into(&mut out, h, planar);
    out
}

/// Decodes and validates one message. Never panics, whatever the bytes.
pub fn decode(b: &[u8]) -> Result<Chunk<'_>, DecodeError> {
    if b.len() < MIN_HEADER_LEN {
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
        bound_ns: bassport::format::BOUND_UNKNOWN,
        missing_channels: 0,
        unaligned_channels: 0,
    };
    let field = |field, value: u64| Err(DecodeError::Field { field, value });
    let hl = usize::from(h.header_len);
    if hl < MIN_HEADER_LEN || hl > b.len() {
        return field("header_len", hl as u64);
    }
    // Read only when the header holds them (not a 96-byte header of before 2026-12-03).
    let h = if hl >= HEADER_LEN {
        Header {
            bound_ns: u64_at(offset_of!(Header, bound_ns)),
            missing_channels: u64_at(offset_of!(Header, missing_channels)),
            unaligned_channels: u64_at(offset_of!(Header, unaligned_channels)),
            ..h
        }
    } else {
        h
    };
    if h.flags & !flags::ALL != 0 {
        return field("flags", h.flags.into());
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
    // A mask bit past the channels names no channel.
    let channel_bits = if h.channels >= 64 { u64::MAX } else { (1u64 << h.channels) - 1 };
    if h.missing_channels & !channel_bits != 0 {
        return field("missing_channels", h.missing_channels);
    }
    if h.unaligned_channels & !channel_bits != 0 {
        return field("unaligned_channels", h.unaligned_channels);
    }
    // Frames are numbered from 1 and a source chunk starts at a multiple of its size plus 1.
    let max_frame = bassport::format::MAX_FRAME_INDEX;
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
    Ok(Chunk { header: h, sample_bytes: payload })
}

/// Decodes a message of one or more chunk messages laid end to end (`serve
/// --chunks-per-message N` sends N in one Zenoh message; N = 1 is a plain message). Each is
/// validated as by [`decode`] before any is returned: a truncated or malformed part refuses
/// the whole message. The chunks come from the returned iterator (nothing is allocated).
pub fn decode_batch(b: &[u8]) -> Result<Chunks<'_>, DecodeError> {
    let mut rest = b;
    let mut count = 0usize;
    while !rest.is_empty() {
        let len = message_len(rest)?;
        decode(&rest[..len])?;
        rest = &rest[len..];
        count += 1;
    }
    if count == 0 {
        return Err(DecodeError::Short(0));
    }
    Ok(Chunks { rest: b, left: count })
}

/// The chunks of a validated message ([`decode_batch`]).
#[derive(Clone, Debug)]
pub struct Chunks<'a> {
    rest: &'a [u8],
    left: usize,
}

impl<'a> Iterator for Chunks<'a> {
    type Item = Chunk<'a>;

    fn next(&mut self) -> Option<Chunk<'a>> {
        // Validated whole by decode_batch: neither call fails here.
        let len = message_len(self.rest).ok()?;
        let c = decode(&self.rest[..len]).ok()?;
        self.rest = &self.rest[len..];
        self.left -= 1;
        Some(c)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.left, Some(self.left))
    }
}

impl ExactSizeIterator for Chunks<'_> {}

/// The length of the chunk message at the start of `b`, from its header (header length,
/// frames, channels, GAP), checked against what `b` holds.
fn message_len(b: &[u8]) -> Result<usize, DecodeError> {
    if b.len() < MIN_HEADER_LEN {
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
    let len = hl.max(MIN_HEADER_LEN) + payload;
    if len > b.len() {
        return Err(DecodeError::Payload { found: b.len().saturating_sub(hl), expected: payload });
    }
    Ok(len)
}

/// Chunk messages waiting to go out together in one Zenoh message (`serve
/// --chunks-per-message`): each chunk is encoded straight into the batch's buffer.
#[derive(Debug, Default)]
pub struct Batch {
    max: u64,
    bytes: Vec<u8>,
    chunks: u64,
    first_sequence: u64,
    frames: u64,
}

/// A full batch, taken from [`Batch::take`].
#[derive(Debug)]
pub struct Taken {
    /// The first chunk's sequence number.
    pub first_sequence: u64,
    /// The Zenoh message: the chunk messages end to end.
    pub bytes: Vec<u8>,
    /// Chunks in it.
    pub chunks: u64,
    /// Frames in it.
    pub frames: u64,
}

impl Batch {
    /// A batch of up to `max` chunks (at least 1).
    pub fn new(max: u32) -> Batch {
        Batch { max: u64::from(max.max(1)), ..Default::default() }
    }

    /// Adds one chunk (see [`encode_into`]); returns whether the batch is now full.
    pub fn push(&mut self, h: &Header, planar: &[i32]) -> bool {
        if self.chunks == 0 {
            self.first_sequence = h.sequence;
            let per = HEADER_LEN + planar.len() * 4;
            self.bytes = Vec::with_capacity(per * self.max as usize);
        }
        encode_into(&mut self.bytes, h, planar);
        self.chunks += 1;
        self.frames += u64::from(h.frames);
        self.chunks >= self.max
    }

    /// The chunks waiting, if any; the batch is empty afterwards.
    pub fn take(&mut self) -> Option<Taken> {
        if self.chunks == 0 {
            return None;
        }
        let t = Taken {
            first_sequence: self.first_sequence,
            bytes: std::mem::take(&mut self.bytes),
            chunks: self.chunks,
            frames: self.frames,
        };
        (self.chunks, self.frames) = (0, 0);
        Some(t)
    }
}

#[cfg(test)]
mod tests;
