//! What the reader's calls return: a read, a view, a chunk's description, a header snapshot.

use crate::format::{Geometry, State};

/// Result of one `getAudioData` call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Read {
    /// Frames delivered (`n`).
    pub frames: usize,
    /// Frames lost before them.
    pub loss: u64,
}

/// A snapshot of the header.
#[derive(Clone, Debug, PartialEq)]
pub struct PortInfo {
    /// Geometry.
    pub geometry: Geometry,
    /// nFOP.
    pub frames_on_port: u64,
    /// Newest frame.
    pub last_frame_index: u64,
    /// Acquisition epoch.
    pub epoch: u64,
    /// State (None if the header holds an unknown value).
    pub state: Option<State>,
    /// Error code (see `format::error_code`).
    pub error_code: u32,
    /// Error message.
    pub message: String,
    /// Device name.
    pub device: String,
    /// Recovered overruns.
    pub xruns: u64,
    /// Zero-filled gap frames.
    pub gap_frames: u64,
    /// Of those, frames lost upstream or on the network (replica ports; 0 otherwise).
    pub lost_upstream_frames: u64,
    /// Chunks published.
    pub chunks_published: u64,
    /// Device rate estimate in Hz (0 = none yet).
    pub rate_estimate_hz: f64,
    /// Writer pid (in the writer's own pid namespace).
    pub writer_pid: u32,
    /// Whether the writer process is alive (in another pid namespace: whether its heartbeat
    /// is younger than [`crate::reader::FOREIGN_WRITER_SILENCE`] plus two chunk periods).
    pub writer_alive: bool,
    /// CLOCK_MONOTONIC (ns) of the acquisition start.
    pub started_mono_ns: u64,
    /// CLOCK_MONOTONIC (ns) of the writer's last sign of life.
    pub heartbeat_mono_ns: u64,
    /// Minor format version.
    pub version_minor: u32,
}

/// Timestamps and flags of the chunk holding a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChunkInfo {
    /// The chunk's first frame.
    pub first_frame: u64,
    /// Frames in the chunk.
    pub frames: u32,
    /// CLOCK_MONOTONIC (ns) of the first frame.
    pub mono_ns: u64,
    /// CLOCK_REALTIME (ns) of the first frame.
    pub realtime_ns: u64,
    /// `format::chunk_flags`.
    pub flags: u32,
    /// Bound (ns) of the timestamps' error ([`crate::format::ChunkExt::bound_ns`]);
    /// [`crate::format::BOUND_UNKNOWN`] if none is known or the port has no extension table.
    pub bound_ns: u64,
    /// Channels whose frames in this chunk are not real ([`crate::format::ChunkExt`]).
    pub missing_channels: u64,
    /// Channels not yet aligned within their bound ([`crate::format::ChunkExt`]).
    pub unaligned_channels: u64,
}

impl ChunkInfo {
    /// The timestamp bound, if known.
    pub fn bound(&self) -> Option<u64> {
        Some(self.bound_ns).filter(|&b| b != crate::format::BOUND_UNKNOWN)
    }
}

/// Frames to be read in place; valid only after [`Port::view_overwritten`] says so.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct View {
    /// First frame of the view.
    pub first_frame: u64,
    /// Frames in the view.
    pub frames: usize,
    /// Frames lost before the view.
    pub loss: u64,
    /// (start slot, length) of up to two ring segments, the same for every channel.
    pub segments: [(usize, usize); 2],
}
