//! The control protocol's messages: one Rust type per request and reply, with derived
//! (serde) encoders. These types are the protocol's only definition; [`super::wire`] puts
//! them into a datagram and docs/control-protocol.md shows them as JSON.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::format::State;

/// The seed's default device.
pub const DEFAULT_DEVICE: &str = "hw:1,0";
/// The seed's default sample rate (Hz).
pub const DEFAULT_SAMPLE_RATE: u32 = 44100;
/// The seed's default nFramesPerChunk.
pub const DEFAULT_FRAMES_PER_CHUNK: u32 = 2205;
/// The seed's default nChunksOnPort.
pub const DEFAULT_CHUNKS_ON_PORT: u32 = 20;
/// Default number of channels (binaural).
pub const DEFAULT_CHANNELS: u32 = 2;

/// Parameters of an Acquire. A field left out of the request takes its seed default.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct AcquireRequest {
    /// ALSA PCM name or `sim:...`.
    pub device: String,
    /// Sample rate in Hz.
    pub sample_rate: u32,
    /// nFramesPerChunk.
    pub frames_per_chunk: u32,
    /// nChunksOnPort.
    pub chunks_on_port: u32,
    /// Channels.
    pub channels: u32,
    /// Force one device sample format (`S32_LE`, `S24_LE`, `S24_3LE`, `FLOAT_LE` or
    /// `S16_LE`); `None` = the broker's choice.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub format: Option<String>,
    /// More devices in the same acquisition (docs/multi-device.md): `device` is the master
    /// clock and its `channels` come first; each follower's channels follow, in order,
    /// resampled onto the master's frames. Empty: one device, as before.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub followers: Vec<FollowerRequest>,
}

/// A follower device of an Acquire ([`AcquireRequest::followers`]).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct FollowerRequest {
    /// ALSA PCM name or `sim:...`.
    pub device: String,
    /// Its channels (0: as many as the master's).
    pub channels: u32,
}

impl Default for AcquireRequest {
    fn default() -> Self {
        AcquireRequest {
            device: DEFAULT_DEVICE.into(),
            sample_rate: DEFAULT_SAMPLE_RATE,
            frames_per_chunk: DEFAULT_FRAMES_PER_CHUNK,
            chunks_on_port: DEFAULT_CHUNKS_ON_PORT,
            channels: DEFAULT_CHANNELS,
            format: None,
            followers: Vec::new(),
        }
    }
}

/// A request to the broker (`"request"` names the variant on the wire).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "request", rename_all = "kebab-case")]
pub enum Request {
    /// List capture devices.
    ListDevices,
    /// Start (or restart) an acquisition.
    Acquire(AcquireRequest),
    /// Stop the acquisition.
    Stop,
    /// The broker's and the port's state.
    Status,
    /// The current port for reading: a broker whose port is a sealed memfd answers
    /// [`Reply::PortFd`] with a read-only descriptor of it attached (SCM_RIGHTS); one whose
    /// port is a file answers [`Reply::PortFile`] (open the path).
    OpenPort,
}

/// Reply to an Acquire.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Acquired {
    /// Epoch of the new acquisition's port.
    pub epoch: u64,
    /// Path of the port file.
    pub port: PathBuf,
    /// Device sample format negotiated (e.g. `S16_LE`; `S32_LE` for simulated devices).
    pub format: String,
    /// Devices in the acquisition (master and followers); 0 (left out) from a broker that
    /// predates followers, which a client that asked for followers must treat as a refusal.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub devices: u32,
}

fn is_zero(n: &u32) -> bool {
    *n == 0
}

/// Answer to OpenPort when the port is a sealed memfd: its descriptor travels with this
/// message as SCM_RIGHTS ancillary data (exactly one descriptor).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PortFd {
    /// Epoch of the port.
    pub epoch: u64,
    /// Bytes of the port (the descriptor's size, sealed).
    pub size: u64,
}

/// A capture device.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeviceInfo {
    /// Name to pass to Acquire.
    pub name: String,
    /// One-line description.
    #[serde(default)]
    pub description: String,
}

/// The broker's and its current port's state. A field a newer broker adds is ignored; a
/// field an older broker leaves out takes its zero value.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Status {
    /// Port state ([`State`] as u32; `Idle` before the first Acquire).
    pub state: u32,
    /// `format::error_code` when `state` is Error.
    pub error_code: u32,
    /// Sample rate (Hz).
    pub sample_rate: u32,
    /// nFramesPerChunk.
    pub frames_per_chunk: u32,
    /// nChunksOnPort.
    pub chunks_on_port: u32,
    /// Channels.
    pub channels: u32,
    /// Acquisition epoch (0 before the first Acquire).
    pub epoch: u64,
    /// Newest published frame.
    pub last_frame_index: u64,
    /// Recovered overruns.
    pub xruns: u64,
    /// Zero-filled frames.
    pub gap_frames: u64,
    /// Chunks published.
    pub chunks_published: u64,
    /// Device rate estimate (Hz; 0 = none yet).
    pub rate_estimate_hz: f64,
    /// Device name.
    pub device: String,
    /// Device sample format negotiated.
    pub format: String,
    /// Error (or information) message.
    pub message: String,
    /// Path of the port file ("" before the first Acquire).
    pub port: String,
    /// Broker process id.
    pub broker_pid: u32,
    /// Broker version.
    pub broker_version: String,
    /// Per device of a several-device acquisition (master first); empty for one device.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub devices: Vec<DeviceStatus>,
    /// For a replica (`bass-bridge mirror`), what the mirror knows of its link and source;
    /// absent for a broker.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub replica: Option<Box<ReplicaStatus>>,
}

/// One device of a several-device acquisition, in Status (docs/multi-device.md).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DeviceStatus {
    /// Device name.
    pub name: String,
    /// `master` or `follower`.
    pub role: String,
    /// Its first channel on the port.
    pub first_channel: u32,
    /// Its channels.
    pub channels: u32,
    /// A follower's state: `waiting` (no frames yet), `aligning` (not yet within its bound),
    /// `locked`, `lost` (unplugged, being reopened); the master's: `master`.
    pub state: String,
    /// Measured rate against the master, ppm (follower frames per master frame - 1; 0 for
    /// the master).
    pub ratio_ppm: f64,
    /// The current alignment error estimate, samples (a follower's; 0 for the master).
    pub error_estimate: f64,
    /// Times it locked.
    pub locks: u64,
    /// Recovered overruns.
    pub xruns: u64,
    /// Times it was lost (unplugged) and reopened.
    pub unplugs: u64,
    /// Port frames whose samples of its channels are missing (zeros, `missing_channels`),
    /// after its first aligned frame.
    pub missing_frames: u64,
    /// Port frames published while it was not locked (`unaligned_channels`).
    pub unaligned_frames: u64,
}

/// What a mirror answers about its replica without asking the source (Status on a replica's
/// control socket): the link, the source's last known state, the counts of what never came.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ReplicaStatus {
    /// The source broker's name.
    pub source: String,
    /// Whether the source was heard within the mirror's timeout.
    pub link_up: bool,
    /// Seconds since the link went up or down (since the mirror started, if it never changed).
    pub link_since_s: f64,
    /// The source's last known state (`capturing`, `stopped`, `error`, `gone`, ...).
    pub source_state: String,
    /// The source's epoch the replica follows.
    pub source_epoch: u64,
    /// The newest source frame the mirror heard of.
    pub source_last_frame_index: u64,
    /// Frames the replica published as GAP for chunks that never arrived.
    pub gap_frames_lost: u64,
    /// Of those, frames the source reported as not sent.
    pub gap_frames_source: u64,
    /// Times the replica went into the error state (link silent, or the source failed).
    pub outages: u64,
    /// Messages dropped for lacking the source's signature.
    pub forged_messages: u64,
    /// The source's own live Status, when the source allows this mirror control
    /// (`serve --allow-control`) and answers; None otherwise.
    pub source_status: Option<Box<Status>>,
}

impl Status {
    /// The port state, decoded.
    pub fn state(&self) -> Option<State> {
        State::from_u32(self.state)
    }

    /// The port state's name (`"capturing"`; "unknown" for a value this library does not know,
    /// e.g. from a newer broker). `state` stays a number on the wire, as in the C
    /// `bass_broker_status`, so any broker's Status decodes; the names are [`State::name`]'s.
    pub fn state_name(&self) -> &'static str {
        State::name_of(self.state)
    }
}

/// Why the broker refused a request (`kind` of an `error` reply).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ErrorKind {
    /// A parameter is out of range or malformed; nothing was changed.
    InvalidArgument,
    /// The device could not be opened or configured; nothing was changed (the message says
    /// what was kept).
    Device,
    /// The peer is not allowed to control this broker.
    Permission,
    /// Another protocol version.
    Version,
    /// A malformed message or an unknown request.
    Protocol,
    /// Anything else (e.g. the port file could not be created).
    Internal,
}

impl ErrorKind {
    /// Wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorKind::InvalidArgument => "invalid-argument",
            ErrorKind::Device => "device",
            ErrorKind::Permission => "permission",
            ErrorKind::Version => "version",
            ErrorKind::Protocol => "protocol",
            ErrorKind::Internal => "internal",
        }
    }
}

/// A reply of the broker (`"reply"` names the variant on the wire): one success variant
/// per request, or an error.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "reply", rename_all = "kebab-case")]
pub enum Reply {
    /// Answer to ListDevices: the simulated devices first, then ALSA's capture PCMs.
    Devices {
        /// The devices.
        devices: Vec<DeviceInfo>,
    },
    /// Answer to Acquire.
    Acquired(Acquired),
    /// Answer to Stop.
    Stopped {
        /// What was stopped (for a human).
        #[serde(default)]
        message: String,
    },
    /// Answer to Status.
    Status(Status),
    /// Answer to OpenPort: the port is a sealed memfd, its descriptor is attached.
    PortFd(PortFd),
    /// Answer to OpenPort: the port is a plain file; open it by path.
    PortFile {
        /// Path of the port file.
        port: PathBuf,
    },
    /// The request was refused.
    Error {
        /// Why.
        kind: ErrorKind,
        /// One line for a human.
        message: String,
    },
}

impl Reply {
    /// An `error` reply.
    pub fn error(kind: ErrorKind, message: &str) -> Reply {
        Reply::Error { kind, message: message.to_owned() }
    }
}
