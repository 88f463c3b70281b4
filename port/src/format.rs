//! The port format (version 2.4: [`VERSION_MAJOR`], [`VERSION_MINOR`]): the one definition of
//! the shared-memory layout.
//!
//! A port is one file (by default in `/dev/shm`) holding one acquisition.
//! Its geometry never changes; a new acquisition gets a new file.
//!
//! ```text
//!  offset 0                4096               4096 + 32*nCOP  (page aligned)
//!  +-----------------------+-------------------+--------------------------------+
//!  | Header (4096 bytes)   | chunk table       | sample rings, channel-planar   |
//!  | magic, version, geom, | nCOP entries of   | ch 0: nFOP x i32 | ch 1: ...   |
//!  | state, lfi, intent,   | 32 bytes: first   | frame f lives in slot          |
//!  | futex, counters, msg  | frame, timestamps,|   (f - 1) mod nFOP             |
//!  |                       | flags             | of every channel ring          |
//!  +-----------------------+-------------------+--------------------------------+
//! ```
//!
//! nFOP = nFramesPerChunk * nChunksOnPort. Chunk c (0-based; frames
//! c*nFPC+1 ..= (c+1)*nFPC) lives in chunk slot c mod nCOP and never wraps
//! inside a ring. Every field is accessed atomically because another process
//! writes it while we read. The byte order is the host's (ports never leave
//! the machine); the magic tells a foreign byte order apart.
//!
//! See docs/port-format.md for the versioning rules and the protocol.

use std::mem::{offset_of, size_of};
use std::sync::atomic::{AtomicI32, AtomicU32, AtomicU64};

use crate::error::Error;

/// `b"BASSPORT"` read as a little-endian u64.
pub const MAGIC: u64 = u64::from_le_bytes(*b"BASSPORT");
/// Major version: readers refuse any other major.
pub const VERSION_MAJOR: u32 = 2;
/// Minor version: additions that old readers may ignore.
/// 1 added state 5 (starting) and `lost_upstream_frames` (offset 192, zero in minor-0 ports);
/// 2 added `restart_grace_ms` (offset 104, zero in older ports); 3 added `writer_pid_ns`
/// (offset 112, zero in older ports); 4 added the chunk extension table (`ext_table_offset`,
/// offset 120; zero in older ports: no table).
pub const VERSION_MINOR: u32 = 4;
/// The longest `restart_grace_ms` a reader honours (1 hour; `bassd --restart-grace-ms` allows
/// no more): a larger value read from a header is taken as this.
pub const MAX_RESTART_GRACE_MS: u32 = 3_600_000;
/// Size of the header, one page.
pub const HEADER_SIZE: usize = 4096;
/// Size of one chunk-table entry.
pub const CHUNK_ENTRY_SIZE: usize = 32;
/// Size of one chunk-extension-table entry (minor 4).
pub const CHUNK_EXT_SIZE: usize = 32;
/// Alignment of the chunk extension table.
pub const EXT_ALIGN: u64 = 64;
/// `bound_ns` of a chunk whose timestamp has no known bound (and of every chunk of a port
/// without an extension table).
pub const BOUND_UNKNOWN: u64 = u64::MAX;
/// Alignment of the sample rings.
pub const SAMPLES_ALIGN: u64 = 4096;
/// Sample format code for signed 32-bit samples in host byte order.
pub const SAMPLE_FORMAT_S32: u32 = 1;
/// Most channels a port may carry.
pub const MAX_CHANNELS: u32 = 64;
/// Highest sample rate an acquisition may have (Hz): the bound of every Acquire, whatever an
/// operator allows (`basskit::limits::Limits` holds the operator's narrower bounds).
pub const MAX_SAMPLE_RATE: u32 = 768_000;
/// Largest valid frame index; beyond it a header is corrupt (a million years at 192 kHz
/// is far below this), and `frame + nFOP` can never overflow.
pub const MAX_FRAME_INDEX: u64 = 1 << 62;
/// Largest port file this format describes (64 GiB).
pub const MAX_TOTAL_SIZE: u64 = 64 << 30;
/// Bytes of the error message field.
pub const MESSAGE_LEN: usize = 256;
/// Bytes of the device name field.
pub const DEVICE_LEN: usize = 128;

/// Acquisition state of a port.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum State {
    /// No acquisition (the broker has not acquired since it started). Ports written by
    /// format 1.0 writers also show it between creation and the first chunk.
    Idle = 0,
    /// Chunks are being published.
    Capturing = 1,
    /// Stopped by request; the window keeps its last frames.
    Stopped = 2,
    /// The acquisition ended on an error (see error code and message).
    Error = 3,
    /// A newer acquisition replaced this port file; reopen the port by name.
    Superseded = 4,
    /// Acquire accepted, the device is open, no chunk published yet (the port of a
    /// brand-new acquisition). Added in format 2.1; values are never renumbered.
    Starting = 5,
}

impl State {
    /// Decodes a state read from shared memory.
    pub fn from_u32(v: u32) -> Option<State> {
        Some(match v {
            0 => State::Idle,
            1 => State::Capturing,
            2 => State::Stopped,
            3 => State::Error,
            4 => State::Superseded,
            5 => State::Starting,
            _ => return None,
        })
    }

    /// The state's name as every tool and binding shows it (`"capturing"`), NUL-terminated for
    /// C (`bass_state_str`). The one spelling of the states: the match is exhaustive, so a new
    /// state does not compile without its name.
    pub const fn c_name(self) -> &'static std::ffi::CStr {
        match self {
            State::Idle => c"idle",
            State::Capturing => c"capturing",
            State::Stopped => c"stopped",
            State::Error => c"error",
            State::Superseded => c"superseded",
            State::Starting => c"starting",
        }
    }

    /// The state's name (`"capturing"`); see [`State::c_name`].
    ///
    /// ```
    /// use bassport::format::State;
    /// assert_eq!(State::Starting.name(), "starting");
    /// assert_eq!(State::from_u32(1).map(State::name), Some("capturing"));
    /// ```
    pub fn name(self) -> &'static str {
        // Every name above is ASCII.
        self.c_name().to_str().unwrap_or("?")
    }

    /// The name of a state value read from shared memory or a message: "unknown" for a value
    /// no state has.
    pub fn name_of(v: u32) -> &'static str {
        State::from_u32(v).map_or("unknown", State::name)
    }
}

/// Why an acquisition ended in [`State::Error`] (the header's `error_code`).
pub mod error_code {
    /// No error.
    pub const NONE: u32 = 0;
    /// The device disappeared or returned a fatal error (e.g. ENODEV).
    pub const DEVICE_LOST: u32 = 1;
    /// The device stopped delivering data (stall watchdog).
    pub const DEVICE_STALLED: u32 = 2;
    /// The device could not be configured as requested.
    pub const CONFIG: u32 = 3;
    /// Anything else.
    pub const INTERNAL: u32 = 4;
}

/// Chunk flags (the chunk table's `flags`).
pub mod chunk_flags {
    /// The chunk is zero-filled: it stands for frames the device did not deliver
    /// (an overrun or a gap), so that frame indices stay proportional to time.
    pub const GAP: u32 = 1;
    /// The first chunk after a recovered overrun or a restart of the stream.
    pub const DISCONTINUITY: u32 = 2;
    /// The timestamps are estimated (from the sample clock) rather than read from the device.
    pub const TIME_ESTIMATED: u32 = 4;
    /// Delivered late: the chunk reached the port more than a chunk's duration (at least
    /// 1 ms) after its last frame was due — the capture fell behind (its thread was starved
    /// or stopped) and the device read came late, in a catch-up burst, or the thread was held
    /// that long between the read that gave its last frames and the port. Its timestamp is
    /// still the frames' capture time. The rate estimate does not use a late read's arrival.
    pub const LATE: u32 = 8;
}

/// The port header, exactly as it lies in shared memory.
#[repr(C)]
pub struct Header {
    /// [`MAGIC`].
    pub magic: AtomicU64,
    /// [`VERSION_MAJOR`]; written last when a port is created (0 = not ready).
    pub version_major: AtomicU32,
    /// [`VERSION_MINOR`].
    pub version_minor: AtomicU32,
    /// [`HEADER_SIZE`].
    pub header_size: AtomicU32,
    /// Number of channels (1..=64; 2 for binaural).
    pub channels: AtomicU32,
    /// [`SAMPLE_FORMAT_S32`].
    pub sample_format: AtomicU32,
    /// Sample rate in Hz.
    pub sample_rate: AtomicU32,
    /// nFPC.
    pub frames_per_chunk: AtomicU32,
    /// nCOP.
    pub chunks_on_port: AtomicU32,
    /// Byte offset of the chunk table (= header size).
    pub chunk_table_offset: AtomicU64,
    /// Byte offset of channel 0's ring.
    pub samples_offset: AtomicU64,
    /// Total file size in bytes.
    pub total_size: AtomicU64,
    /// Acquisition epoch: differs for every acquisition of a broker.
    pub epoch: AtomicU64,
    /// Writer process id.
    pub writer_pid: AtomicU32,
    /// [`State`].
    pub state: AtomicU32,
    /// Writer process start time (clock ticks after boot, /proc/PID/stat field 22),
    /// so that a recycled pid is not mistaken for the writer.
    pub writer_start_time: AtomicU64,
    /// CLOCK_REALTIME (ns) at which the port was created.
    pub created_realtime_ns: AtomicU64,
    /// [`error_code`] when `state` is Error.
    pub error_code: AtomicU32,
    /// Futex word: incremented (and woken) on every publish and state change.
    pub futex: AtomicU32,
    /// How long (ms after its last heartbeat) a dead writer may be replaced by its successor
    /// taking the same port back (a broker restarted by its service manager); readers wait
    /// that long before they report the writer gone. 0 = a dead writer is gone (minor 2).
    pub restart_grace_ms: AtomicU32,
    _pad0: [u8; 4],
    /// The writer's pid namespace (the inode of its `/proc/self/ns/pid`; 0 = unknown): a reader
    /// in another pid namespace cannot look `writer_pid` up and goes by the heartbeat (minor 3).
    pub writer_pid_ns: AtomicU64,
    /// Byte offset of the chunk extension table ([`ChunkExt`]; minor 4): total_size rounded up
    /// to [`EXT_ALIGN`]; 0 = the port has none (older writers).
    pub ext_table_offset: AtomicU64,
    /// Index of the newest published frame (frames are numbered from 1).
    pub last_frame_index: AtomicU64,
    /// Highest frame index the writer may be writing now (>= last_frame_index).
    pub write_intent: AtomicU64,
    /// CLOCK_MONOTONIC (ns) of the writer's last publish or heartbeat.
    pub heartbeat_mono_ns: AtomicU64,
    /// Device overruns recovered.
    pub xruns: AtomicU64,
    /// Zero-filled frames published for device gaps.
    pub gap_frames: AtomicU64,
    /// Chunks published.
    pub chunks_published: AtomicU64,
    /// Estimated device sample rate in milli-Hz (0 = no estimate yet).
    pub rate_estimate_mhz: AtomicU64,
    /// CLOCK_MONOTONIC (ns) at which the acquisition started.
    pub started_mono_ns: AtomicU64,
    /// Frames lost before they reached this port's writer (upstream of a replica, or on the
    /// network) and published as zero-filled GAP frames (minor 1; 0 in older ports).
    pub lost_upstream_frames: AtomicU64,
    _pad2: [u8; 56],
    /// Error message, UTF-8, NUL padded.
    pub message: [AtomicU64; MESSAGE_LEN / 8],
    /// ALSA (or simulated) device name, UTF-8, NUL padded.
    pub device: [AtomicU64; DEVICE_LEN / 8],
    _reserved: [u8; HEADER_SIZE - 640],
}

const _: () = assert!(size_of::<Header>() == HEADER_SIZE);
const _: () = assert!(offset_of!(Header, version_major) == 8);
const _: () = assert!(offset_of!(Header, channels) == 20);
const _: () = assert!(offset_of!(Header, chunks_on_port) == 36);
const _: () = assert!(offset_of!(Header, epoch) == 64);
const _: () = assert!(offset_of!(Header, futex) == 100);
const _: () = assert!(offset_of!(Header, restart_grace_ms) == 104);
const _: () = assert!(offset_of!(Header, writer_pid_ns) == 112);
const _: () = assert!(offset_of!(Header, ext_table_offset) == 120);
const _: () = assert!(offset_of!(Header, last_frame_index) == 128);
const _: () = assert!(offset_of!(Header, write_intent) == 136);
const _: () = assert!(offset_of!(Header, started_mono_ns) == 184);
const _: () = assert!(offset_of!(Header, lost_upstream_frames) == 192);
const _: () = assert!(offset_of!(Header, message) == 256);
const _: () = assert!(offset_of!(Header, device) == 512);

/// One chunk-table entry.
#[repr(C)]
pub struct ChunkEntry {
    /// Index of the chunk's first frame.
    pub first_frame: AtomicU64,
    /// CLOCK_MONOTONIC (ns) of the first frame's capture.
    pub mono_ns: AtomicU64,
    /// CLOCK_REALTIME (ns) of the first frame's capture.
    pub realtime_ns: AtomicU64,
    /// [`chunk_flags`].
    pub flags: AtomicU32,
    /// Frames in the chunk (= nFPC).
    pub frames: AtomicU32,
}

const _: () = assert!(size_of::<ChunkEntry>() == CHUNK_ENTRY_SIZE);

/// One chunk-extension-table entry (minor 4), written with the chunk's [`ChunkEntry`] before
/// its frames are published; valid for a chunk only while `first_frame` equals the chunk's.
#[repr(C)]
pub struct ChunkExt {
    /// Index of the chunk's first frame: the row belongs to that chunk.
    pub first_frame: AtomicU64,
    /// Half-width (ns) of the interval around `mono_ns` (and `realtime_ns`) in which the first
    /// frame's true capture time lies; [`BOUND_UNKNOWN`] if none is known.
    pub bound_ns: AtomicU64,
    /// Bit c set: channel c's frames in this chunk are not real (zero-filled: the device
    /// feeding that channel lost them), though the chunk as a whole is not a GAP.
    pub missing_channels: AtomicU64,
    /// Bit c set: channel c is resampled from a follower device whose alignment to the
    /// master's frame index is not yet within its bound (before lock).
    pub unaligned_channels: AtomicU64,
}

const _: () = assert!(size_of::<ChunkExt>() == CHUNK_EXT_SIZE);
const _: () = assert!(size_of::<AtomicI32>() == 4);

/// The immutable geometry of a port, validated.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Geometry {
    /// Channels.
    pub channels: u32,
    /// Sample rate in Hz.
    pub sample_rate: u32,
    /// nFPC.
    pub frames_per_chunk: u32,
    /// nCOP.
    pub chunks_on_port: u32,
}

/// Byte offsets derived from a [`Geometry`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// nFOP.
    pub frames_on_port: u64,
    /// Offset of the chunk table.
    pub chunk_table_offset: u64,
    /// Offset of channel 0's ring.
    pub samples_offset: u64,
    /// End of the sample rings: the header's `total_size`.
    pub total_size: u64,
    /// Offset of the chunk extension table; 0 = none (a port of an older writer).
    pub ext_table_offset: u64,
    /// Bytes the port occupies: `total_size`, or the end of the extension table.
    pub mapped_size: u64,
}

impl Geometry {
    /// One chunk's duration at the nominal rate, in nanoseconds (at least 1).
    pub fn chunk_ns(&self) -> u64 {
        (u64::from(self.frames_per_chunk) * 1_000_000_000 / u64::from(self.sample_rate.max(1))).max(1)
    }

    /// Checks the ranges and computes the layout, with overflow checks.
    pub fn layout(&self) -> Result<Layout, Error> {
        if self.channels == 0 || self.channels > MAX_CHANNELS {
            return Err(Error::InvalidArgument(format!(
                "channels = {} (must be 1..={MAX_CHANNELS})",
                self.channels
            )));
        }
        if self.sample_rate == 0 {
            return Err(Error::InvalidArgument("sampleRate = 0 Hz (must be at least 1)".into()));
        }
        if self.frames_per_chunk == 0 {
            return Err(Error::InvalidArgument("nFramesPerChunk = 0 (must be at least 1)".into()));
        }
        if self.chunks_on_port == 0 {
            return Err(Error::InvalidArgument("nChunksOnPort = 0 (must be at least 1)".into()));
        }
        let frames_on_port = u64::from(self.frames_per_chunk) * u64::from(self.chunks_on_port);
        let too_big = || {
            Error::InvalidArgument(format!(
                "nFramesPerChunk * nChunksOnPort * channels = {} * {} * {} samples exceeds the format's limit of {} bytes",
                self.frames_per_chunk, self.chunks_on_port, self.channels, MAX_TOTAL_SIZE
            ))
        };
        let chunk_table_offset = HEADER_SIZE as u64;
        let table_end = chunk_table_offset + u64::from(self.chunks_on_port) * CHUNK_ENTRY_SIZE as u64;
        let samples_offset = table_end.div_ceil(SAMPLES_ALIGN) * SAMPLES_ALIGN;
        // Samples are stored two per 8-byte word (see `ring`): an odd sample count is
        // padded to a whole word.
        let ring_bytes = frames_on_port
            .checked_mul(u64::from(self.channels))
            .and_then(|n| n.div_ceil(2).checked_mul(8))
            .ok_or_else(too_big)?;
        let total_size = samples_offset.checked_add(ring_bytes).ok_or_else(too_big)?;
        let ext_table_offset = total_size.div_ceil(EXT_ALIGN) * EXT_ALIGN;
        let mapped_size = ext_table_offset + u64::from(self.chunks_on_port) * CHUNK_EXT_SIZE as u64;
        if mapped_size > MAX_TOTAL_SIZE || usize::try_from(mapped_size).is_err() {
            return Err(too_big());
        }
        Ok(Layout {
            frames_on_port,
            chunk_table_offset,
            samples_offset,
            total_size,
            ext_table_offset,
            mapped_size,
        })
    }
}

impl Layout {
    /// The same layout without an extension table (a port of a writer older than minor 4).
    pub fn without_ext(self) -> Layout {
        Layout { ext_table_offset: 0, mapped_size: self.total_size, ..self }
    }
}

/// Everything a reader knows about a port once its header validated.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Validated {
    /// The geometry.
    pub geometry: Geometry,
    /// The layout.
    pub layout: Layout,
    /// Minor version found.
    pub version_minor: u32,
}

/// Validates a header read from a mapping of `file_len` bytes.
///
/// Every field that sizes or locates anything is checked against the format's
/// rules and against the real file length, with overflow checks.
pub fn validate(h: &Header, file_len: u64) -> Result<Validated, Error> {
    use std::sync::atomic::Ordering::{Acquire, Relaxed};
    // The version is written last with Release: once we see it, the rest is there.
    let major = h.version_major.load(Acquire);
    let magic = h.magic.load(Relaxed);
    if magic != MAGIC {
        if magic == 0 && major == 0 {
            return Err(Error::NotReady);
        }
        return Err(Error::BadMagic { found: magic });
    }
    if major == 0 {
        return Err(Error::NotReady);
    }
    if major != VERSION_MAJOR {
        return Err(Error::Incompatible { found: major, expected: VERSION_MAJOR });
    }
    let corrupt = |what: String| Error::Corrupt(what);
    let header_size = h.header_size.load(Relaxed);
    if header_size as usize != HEADER_SIZE {
        return Err(corrupt(format!("header_size = {header_size}, expected {HEADER_SIZE}")));
    }
    let fmt = h.sample_format.load(Relaxed);
    if fmt != SAMPLE_FORMAT_S32 {
        return Err(corrupt(format!("sample_format = {fmt}, expected {SAMPLE_FORMAT_S32} (S32)")));
    }
    let geometry = Geometry {
        channels: h.channels.load(Relaxed),
        sample_rate: h.sample_rate.load(Relaxed),
        frames_per_chunk: h.frames_per_chunk.load(Relaxed),
        chunks_on_port: h.chunks_on_port.load(Relaxed),
    };
    let full = geometry.layout().map_err(|e| corrupt(format!("geometry: {e}")))?;
    let stored =
        (h.chunk_table_offset.load(Relaxed), h.samples_offset.load(Relaxed), h.total_size.load(Relaxed));
    if stored != (full.chunk_table_offset, full.samples_offset, full.total_size) {
        return Err(corrupt(format!(
            "offsets (table {}, samples {}, total {}) disagree with the geometry (table {}, samples {}, total {})",
            stored.0, stored.1, stored.2, full.chunk_table_offset, full.samples_offset, full.total_size
        )));
    }
    let minor = h.version_minor.load(Relaxed);
    // Minor 4 added the extension table; an older writer left the word zero.
    let ext = if minor >= 4 { h.ext_table_offset.load(Relaxed) } else { 0 };
    let layout = match ext {
        0 => full.without_ext(),
        e if e == full.ext_table_offset => full,
        e => {
            return Err(corrupt(format!(
                "ext_table_offset = {e} disagrees with the geometry (expected {} or 0)",
                full.ext_table_offset
            )))
        }
    };
    if layout.mapped_size > file_len {
        return Err(corrupt(format!(
            "file is {file_len} bytes but the header describes {} bytes (truncated?)",
            layout.mapped_size
        )));
    }
    Ok(Validated { geometry, layout, version_minor: minor })
}

/// Reads a NUL-padded text field.
pub fn read_text(words: &[AtomicU64]) -> String {
    let mut bytes = Vec::with_capacity(words.len() * 8);
    for w in words {
        bytes.extend_from_slice(&w.load(std::sync::atomic::Ordering::Relaxed).to_le_bytes());
    }
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

/// Writes a NUL-padded text field, cut at a character boundary to fit (one NUL kept).
pub fn write_text(words: &[AtomicU64], text: &str) {
    let cap = words.len() * 8 - 1;
    let mut end = text.len().min(cap);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    let mut bytes = vec![0u8; words.len() * 8];
    bytes[..end].copy_from_slice(&text.as_bytes()[..end]);
    for (w, b) in words.iter().zip(bytes.chunks_exact(8)) {
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        w.store(u64::from_le_bytes(a), std::sync::atomic::Ordering::Relaxed);
    }
}

/// Ring slot of a frame; defined once, in the window protocol (`ring.rs`, which the loom
/// model compiles on its own and so cannot depend on this module).
pub use crate::ring::slot;
