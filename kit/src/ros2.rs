//! ROS 2 messages of bass: the one definition of the type names, the message definitions and
//! the CDR encoding of what bass puts on a ROS 2 topic or in an MCAP recording.
//!
//! Four messages, each serialised as CDR little-endian (XCDR1, as rmw implementations write
//! it) behind the 4-byte encapsulation header `00 01 00 00`:
//!
//! - [`AudioDataStamped`] (`audio_common_msgs/msg/AudioDataStamped`): one run of frames, its
//!   samples interleaved as signed 32-bit little-endian integers ([`SAMPLE_FORMAT`] `S32LE`),
//!   `header.stamp` the CLOCK_REALTIME of its first frame;
//! - [`AudioInfo`] (`audio_common_msgs/msg/AudioInfo`): channels, rate, `S32LE`, `wave`;
//! - [`ChunkInfo`] (`bass_msgs/msg/ChunkInfo`, bass's own): the frame index, frames, chunk
//!   flags, both clocks and the loss before the audio message with the same stamp, then (added
//!   at its end with port format 2.4) the chunk's timestamp bound and channel masks;
//! - [`foxglove::RawAudio`] (`foxglove_msgs/msg/RawAudio`, Foxglove's): the same run as 16-bit
//!   PCM, for Foxglove's Audio panel (only in MCAP recordings that ask for it).
//!
//! ```text
//!  AudioDataStamped CDR body (offsets after the encapsulation header)
//!  0        4          8          12                   12+n  pad4   +4
//!  +--------+----------+----------+--------------------+-----+-----+----------------------+
//!  | sec i32| nsec u32 | len u32  | frame_id, NUL      | ... | cnt | data: cnt bytes      |
//!  +--------+----------+----------+--------------------+-----+-----+----------------------+
//!   header.stamp        header.frame_id (len counts NUL)       audio.data (uint8[])
//! ```
//!
//! Every primitive is aligned to its own size counted from the start of the body; strings
//! are a u32 length counting the terminating NUL, then the bytes and the NUL. The definitions
//! ([`AUDIO_DATA_STAMPED_DEFINITION`], ...) are the `ros2msg` texts rosbag2 stores as an MCAP
//! schema: the type's own fields first, then each dependency after a line of 80 `=` and a
//! `MSG: pkg/Type` line. The field lists are those of the `audio_common_msgs` (ROS 2 branch),
//! `std_msgs` and `builtin_interfaces` packages; their comments are left out.
//!
//! ```
//! use basskit::ros2::{AudioDataStamped, Header, Time};
//! let header = Header { stamp: Time::from_ns(1_700_000_000_250_000_000), frame_id: String::new() };
//! let mut bytes = Vec::new();
//! AudioDataStamped::encode_samples(&header, &[1, -2, 3, -4], &mut bytes);
//! let msg = AudioDataStamped::decode(&bytes).unwrap();
//! assert_eq!(msg.samples().unwrap(), vec![1, -2, 3, -4]);
//! assert_eq!(msg.header.stamp.to_ns(), Some(1_700_000_000_250_000_000));
//! ```

/// Type name of the audio message.
pub const AUDIO_DATA_STAMPED: &str = "audio_common_msgs/msg/AudioDataStamped";
/// Type name of the stream description.
pub const AUDIO_INFO: &str = "audio_common_msgs/msg/AudioInfo";
/// Type name of bass's per-message frame index, flags and loss.
pub const CHUNK_INFO: &str = "bass_msgs/msg/ChunkInfo";

/// Schema encoding of the definitions (an MCAP schema's `encoding`).
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// Message encoding (an MCAP channel's `message_encoding`, rosbag2's serialization format).
pub const MESSAGE_ENCODING: &str = "cdr";
/// `AudioInfo.sample_format` of bass audio: interleaved signed 32-bit little-endian.
pub const SAMPLE_FORMAT: &str = "S32LE";
/// `AudioInfo.coding_format` of bass audio: uncompressed PCM (audio_capture's `wave`).
pub const CODING_FORMAT: &str = "wave";
/// The encapsulation header of little-endian CDR.
pub const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

const RULE: &str = "================================================================================";

macro_rules! header_deps {
    () => {
        "
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id

================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"
    };
}

/// Complete `ros2msg` definition of [`AUDIO_DATA_STAMPED`].
pub const AUDIO_DATA_STAMPED_DEFINITION: &str = concat!(
    "std_msgs/Header header
audio_common_msgs/AudioData audio

================================================================================
MSG: audio_common_msgs/AudioData
uint8[] data
",
    header_deps!()
);

/// Complete `ros2msg` definition of [`AUDIO_INFO`].
pub const AUDIO_INFO_DEFINITION: &str = "uint8 channels
uint32 sample_rate
string sample_format
uint32 bitrate
string coding_format
";

/// Complete `ros2msg` definition of [`CHUNK_INFO`].
pub const CHUNK_INFO_DEFINITION: &str =
    concat!(include_str!("../../ros2/bass_msgs/msg/ChunkInfo.msg"), header_deps!());

/// Why a CDR payload was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// The payload is shorter than a field needs.
    #[error("{field}: needs {need} bytes at offset {at}, the payload has {len}")]
    Truncated {
        /// Field being read.
        field: &'static str,
        /// Offset in the body.
        at: usize,
        /// Bytes needed from there.
        need: usize,
        /// Body length.
        len: usize,
    },
    /// Not little-endian CDR.
    #[error("encapsulation header {found:02x?} is not little-endian CDR (00 01 xx xx)")]
    Encapsulation {
        /// The first bytes found.
        found: Vec<u8>,
    },
    /// A string without its NUL, or not UTF-8.
    #[error("{field}: not a NUL-terminated UTF-8 string")]
    BadString {
        /// Field being read.
        field: &'static str,
    },
    /// A value out of its range.
    #[error("{field}: {value} is out of range")]
    Range {
        /// Field.
        field: &'static str,
        /// Value found.
        value: u64,
    },
    /// A string field holding another value than the one required.
    #[error("{field}: {found:?}, not {expected:?}")]
    Unexpected {
        /// Field.
        field: &'static str,
        /// Value found.
        found: String,
        /// Value required.
        expected: &'static str,
    },
    /// Bytes after the last field beyond alignment padding.
    #[error("{extra} bytes after the message's last field")]
    Trailing {
        /// Extra bytes.
        extra: usize,
    },
}

/// `builtin_interfaces/msg/Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds, `0..1_000_000_000`.
    pub nanosec: u32,
}

impl Time {
    /// The time `ns` nanoseconds after the Unix epoch; seconds past `i32::MAX` (2038) saturate.
    pub fn from_ns(ns: u64) -> Time {
        let sec = ns / 1_000_000_000;
        if sec > i32::MAX as u64 {
            return Time { sec: i32::MAX, nanosec: 999_999_999 };
        }
        Time { sec: sec as i32, nanosec: (ns % 1_000_000_000) as u32 }
    }

    /// Nanoseconds since the epoch, `None` before it or with `nanosec` out of range.
    pub fn to_ns(self) -> Option<u64> {
        if self.sec < 0 || self.nanosec >= 1_000_000_000 {
            return None;
        }
        Some(self.sec as u64 * 1_000_000_000 + u64::from(self.nanosec))
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Header {
    /// Capture time.
    pub stamp: Time,
    /// Coordinate frame (empty: none).
    pub frame_id: String,
}

/// `audio_common_msgs/msg/AudioDataStamped` (`audio.data` is the only field of `AudioData`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct AudioDataStamped {
    /// Stamp of the first frame.
    pub header: Header,
    /// The samples, interleaved S32LE for bass.
    pub data: Vec<u8>,
}

/// `audio_common_msgs/msg/AudioInfo`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct AudioInfo {
    /// Channels per frame.
    pub channels: u8,
    /// Frames per second.
    pub sample_rate: u32,
    /// [`SAMPLE_FORMAT`] for bass.
    pub sample_format: String,
    /// Bits per second of the data.
    pub bitrate: u32,
    /// [`CODING_FORMAT`] for bass.
    pub coding_format: String,
}

/// `bass_msgs/msg/ChunkInfo`: see [`CHUNK_INFO_DEFINITION`] for each field.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChunkInfo {
    /// The audio message's header.
    pub header: Header,
    /// Acquisition counter of the port.
    pub epoch: u64,
    /// Index of the audio message's first frame.
    pub first_frame: u64,
    /// Frames in the audio message.
    pub frames: u32,
    /// First frame of the chunk holding them, 0 when the chunk's row is not known.
    pub chunk_first_frame: u64,
    /// Frames per chunk of the port.
    pub chunk_frames: u32,
    /// The chunk's flags ([`bassport::format::chunk_flags`]).
    pub flags: u32,
    /// CLOCK_MONOTONIC of the chunk's first frame, ns.
    pub monotonic_ns: u64,
    /// CLOCK_REALTIME of the chunk's first frame, ns.
    pub realtime_ns: u64,
    /// Frames lost between the previous message and this one.
    pub lost_before: u64,
    /// Half-width (ns) of the interval around the chunk's stamps in which its first frame's
    /// true capture time lies; [`BOUND_UNKNOWN`] = not known (and in a message without it).
    pub bound_ns: u64,
    /// Bit c: channel c's frames in the chunk are zeros its device never delivered.
    pub missing_channels: u64,
    /// Bit c: channel c is not yet aligned to the frame index within its bound.
    pub unaligned_channels: u64,
}

/// `ChunkInfo.bound_ns` of a chunk whose bound is not known (the port's own value).
pub const BOUND_UNKNOWN: u64 = bassport::format::BOUND_UNKNOWN;

impl Default for ChunkInfo {
    /// Every field 0 but the bound, unknown.
    fn default() -> Self {
        ChunkInfo {
            header: Header::default(),
            epoch: 0,
            first_frame: 0,
            frames: 0,
            chunk_first_frame: 0,
            chunk_frames: 0,
            flags: 0,
            monotonic_ns: 0,
            realtime_ns: 0,
            lost_before: 0,
            bound_ns: BOUND_UNKNOWN,
            missing_channels: 0,
            unaligned_channels: 0,
        }
    }
}

/// A CDR writer: appends to a buffer, aligning each primitive to its size within the body.
struct Out<'a> {
    buf: &'a mut Vec<u8>,
    body: usize,
}

impl<'a> Out<'a> {
    fn new(buf: &'a mut Vec<u8>) -> Self {
        buf.clear();
        buf.extend_from_slice(&CDR_LE);
        Out { buf, body: CDR_LE.len() }
    }
    fn align(&mut self, n: usize) {
        while (self.buf.len() - self.body) % n != 0 {
            self.buf.push(0);
        }
    }
    fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.u32(v as u32);
    }
    fn u64(&mut self, v: u64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
    fn header(&mut self, h: &Header) {
        self.i32(h.stamp.sec);
        self.u32(h.stamp.nanosec);
        self.string(&h.frame_id);
    }
}

/// A CDR reader over a body, checking every length against what is left.
struct In<'a> {
    body: &'a [u8],
    at: usize,
}

impl<'a> In<'a> {
    fn new(payload: &'a [u8]) -> Result<Self, CdrError> {
        match payload {
            [0x00, 0x01, _, _, body @ ..] => Ok(In { body, at: 0 }),
            _ => Err(CdrError::Encapsulation { found: payload[..payload.len().min(4)].to_vec() }),
        }
    }
    fn take(&mut self, field: &'static str, align: usize, need: usize) -> Result<&'a [u8], CdrError> {
        let at = self.at.next_multiple_of(align);
        let end = at.checked_add(need).filter(|&e| e <= self.body.len());
        let end = end.ok_or(CdrError::Truncated { field, at, need, len: self.body.len() })?;
        self.at = end;
        Ok(&self.body[at..end])
    }
    fn u8(&mut self, field: &'static str) -> Result<u8, CdrError> {
        Ok(self.take(field, 1, 1)?[0])
    }
    fn u32(&mut self, field: &'static str) -> Result<u32, CdrError> {
        let b = self.take(field, 4, 4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self, field: &'static str) -> Result<u64, CdrError> {
        let b = self.take(field, 8, 8)?;
        Ok(u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
    }
    fn bytes(&mut self, field: &'static str) -> Result<&'a [u8], CdrError> {
        let n = self.u32(field)? as usize;
        self.take(field, 1, n)
    }
    fn string(&mut self, field: &'static str) -> Result<String, CdrError> {
        match self.bytes(field)? {
            [s @ .., 0] => std::str::from_utf8(s)
                .ok()
                .filter(|s| !s.contains('\0'))
                .map(str::to_owned)
                .ok_or(CdrError::BadString { field }),
            _ => Err(CdrError::BadString { field }),
        }
    }
    fn header(&mut self) -> Result<Header, CdrError> {
        let sec = self.u32("header.stamp.sec")? as i32;
        let nanosec = self.u32("header.stamp.nanosec")?;
        if nanosec >= 1_000_000_000 {
            return Err(CdrError::Range { field: "header.stamp.nanosec", value: nanosec.into() });
        }
        Ok(Header { stamp: Time { sec, nanosec }, frame_id: self.string("header.frame_id")? })
    }
    /// Accepts up to 7 bytes of padding after the last field (writers may pad to 8).
    fn end(self) -> Result<(), CdrError> {
        match self.body.len() - self.at {
            extra @ 8.. => Err(CdrError::Trailing { extra }),
            _ => Ok(()),
        }
    }
}

impl AudioDataStamped {
    /// Serialises `header` and `samples` (interleaved frames) as S32LE, without an
    /// intermediate byte buffer. `out` is cleared first.
    pub fn encode_samples(header: &Header, samples: &[i32], out: &mut Vec<u8>) {
        let mut o = Out::new(out);
        o.header(header);
        o.u32((samples.len() * 4) as u32);
        o.buf.reserve(samples.len() * 4);
        for s in samples {
            o.buf.extend_from_slice(&s.to_le_bytes());
        }
    }

    /// Serialises the message into `out` (cleared first).
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut o = Out::new(out);
        o.header(&self.header);
        o.u32(self.data.len() as u32);
        o.buf.extend_from_slice(&self.data);
    }

    /// Reads a CDR payload, every length checked.
    pub fn decode(payload: &[u8]) -> Result<Self, CdrError> {
        let mut i = In::new(payload)?;
        let header = i.header()?;
        let data = i.bytes("audio.data")?.to_vec();
        i.end()?;
        Ok(AudioDataStamped { header, data })
    }

    /// The data as S32LE samples; an error if its length is not a whole number of samples.
    pub fn samples(&self) -> Result<Vec<i32>, CdrError> {
        if self.data.len() % 4 != 0 {
            return Err(CdrError::Range { field: "audio.data length", value: self.data.len() as u64 });
        }
        Ok(self.data.chunks_exact(4).map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
    }
}

impl AudioInfo {
    /// The description of bass audio: `channels` interleaved S32LE channels at `sample_rate`.
    pub fn s32le(channels: u8, sample_rate: u32) -> AudioInfo {
        AudioInfo {
            channels,
            sample_rate,
            sample_format: SAMPLE_FORMAT.into(),
            bitrate: sample_rate.saturating_mul(u32::from(channels)).saturating_mul(32),
            coding_format: CODING_FORMAT.into(),
        }
    }

    /// Serialises the message into `out` (cleared first).
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut o = Out::new(out);
        o.u8(self.channels);
        o.u32(self.sample_rate);
        o.string(&self.sample_format);
        o.u32(self.bitrate);
        o.string(&self.coding_format);
    }

    /// Reads a CDR payload, every length checked.
    pub fn decode(payload: &[u8]) -> Result<Self, CdrError> {
        let mut i = In::new(payload)?;
        let m = AudioInfo {
            channels: i.u8("channels")?,
            sample_rate: i.u32("sample_rate")?,
            sample_format: i.string("sample_format")?,
            bitrate: i.u32("bitrate")?,
            coding_format: i.string("coding_format")?,
        };
        i.end()?;
        Ok(m)
    }
}

impl ChunkInfo {
    /// Serialises the message into `out` (cleared first).
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut o = Out::new(out);
        o.header(&self.header);
        o.u64(self.epoch);
        o.u64(self.first_frame);
        o.u32(self.frames);
        o.u64(self.chunk_first_frame);
        o.u32(self.chunk_frames);
        o.u32(self.flags);
        o.u64(self.monotonic_ns);
        o.u64(self.realtime_ns);
        o.u64(self.lost_before);
        o.u64(self.bound_ns);
        o.u64(self.missing_channels);
        o.u64(self.unaligned_channels);
    }

    /// The port chunk's row this message describes; `None` when the recorder had none
    /// (`chunk_first_frame` 0).
    pub fn row(&self) -> Option<crate::sidecar::ChunkRow> {
        (self.chunk_first_frame != 0).then_some(crate::sidecar::ChunkRow {
            first_frame: self.chunk_first_frame,
            frames: self.chunk_frames,
            mono_ns: self.monotonic_ns,
            realtime_ns: self.realtime_ns,
            flags: self.flags,
            bound_ns: Some(self.bound_ns).filter(|&b| b != BOUND_UNKNOWN),
            missing_channels: self.missing_channels,
            unaligned_channels: self.unaligned_channels,
        })
    }

    /// Reads a CDR payload, every length checked (the values' meaning is the reader's to check).
    /// A message that ends after `lost_before` (written before the bound was added) reads as
    /// bound unknown and no channel flagged.
    pub fn decode(payload: &[u8]) -> Result<Self, CdrError> {
        let mut i = In::new(payload)?;
        let m = ChunkInfo {
            header: i.header()?,
            epoch: i.u64("epoch")?,
            first_frame: i.u64("first_frame")?,
            frames: i.u32("frames")?,
            chunk_first_frame: i.u64("chunk_first_frame")?,
            chunk_frames: i.u32("chunk_frames")?,
            flags: i.u32("flags")?,
            monotonic_ns: i.u64("monotonic_ns")?,
            realtime_ns: i.u64("realtime_ns")?,
            lost_before: i.u64("lost_before")?,
            ..ChunkInfo::default()
        };
        if i.body.len() - i.at < 8 {
            i.end()?; // the older message: padding at most
            return Ok(m);
        }
        let m = ChunkInfo {
            bound_ns: i.u64("bound_ns")?,
            missing_channels: i.u64("missing_channels")?,
            unaligned_channels: i.u64("unaligned_channels")?,
            ..m
        };
        i.end()?;
        Ok(m)
    }
}

/// The ROS name token for a bass broker name (`[A-Za-z0-9._-]`): `.` and `-` become `_`,
/// runs of `_` one, and a name starting with a digit gets a leading `b`.
pub fn name_token(broker: &str) -> String {
    let mut t = String::with_capacity(broker.len() + 1);
    for c in broker.chars() {
        let c = if c.is_ascii_alphanumeric() { c } else { '_' };
        if !(c == '_' && t.ends_with('_')) {
            t.push(c);
        }
    }
    let t = t.trim_matches('_').to_string();
    match t.chars().next() {
        None => "bass".into(),
        Some(c) if c.is_ascii_digit() => format!("b{t}"),
        Some(_) => t,
    }
}

/// The topics of a broker's audio: `/bass/<broker>/audio` (AudioDataStamped),
/// `/bass/<broker>/audio_info` (AudioInfo), `/bass/<broker>/chunk_info` (ChunkInfo).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Topics {
    /// AudioDataStamped.
    pub audio: String,
    /// AudioInfo.
    pub info: String,
    /// ChunkInfo.
    pub chunks: String,
}

impl Topics {
    /// The default topics of `broker` (see [`name_token`]).
    pub fn of(broker: &str) -> Topics {
        let base = format!("/bass/{}", name_token(broker));
        Topics {
            audio: format!("{base}/audio"),
            info: format!("{base}/audio_info"),
            chunks: format!("{base}/chunk_info"),
        }
    }
}

/// The definitions' dependency delimiter (80 `=`), for readers that split a definition.
pub fn delimiter(type_name: &str) -> String {
    format!("{RULE}\nMSG: {type_name}\n")
}

pub mod foxglove;

#[cfg(test)]
mod tests;
