//! bass client library: the shared audio port of the bass broker.
//!
//! - [`format`]: the port format (the one definition of the shared layout);
//! - [`ring`]: the lock-free one-writer / many-readers window protocol;
//! - [`writer::Writer`]: creates a port and publishes chunks (used by `bassd`, simulators, tests);
//! - [`reader::Port`]: opens a port read-only; `get_audio_data` is the formal
//!   `getAudioData` algorithm of the BASS documentation;
//! - [`ffi`]: the C ABI (`include/bass.h`);
//! - [`stream`]: callback streams (a closure per block, with its first frame, loss, flags and
//!   timestamps), on the caller's thread or bass's own;
//! - [`ros2`]: the ROS 2 messages of bass (type names, definitions, CDR) for MCAP and topics;
//! - [`sidecar`]: the sidecar of a recording (`FILE.wav.json`), for `bass record` and the replay;
//! - [`access`]: what a client is told when the system refuses it a broker's socket or port;
//! - [`args`]: the command-line vocabulary bassd, bass and bass-bridge share;
//! - [`control`]: the broker's control protocol and its [`control::Client`].
//!
//! The main paths, each with a runnable example: open a port, wait, read
//! ([`Port::open`], [`Port::wait`], [`Port::get_audio_data`], [`Port::chunk_info`]); create a
//! writer and publish ([`Writer::create_at`], [`Writer::publish`]); ask a broker to acquire
//! ([`control::Client`]).

#![warn(missing_docs)]

pub mod access;
pub mod args;
pub mod control;
pub mod error;
pub mod ffi;
pub mod format;
pub mod instance;
pub mod memfd;
pub mod paths;
pub mod portfile;
pub mod reader;
pub mod ring;
pub mod ros2;
mod shm;
pub mod sidecar;
pub mod sigbus;
pub mod stream;
pub mod sys;
pub mod testsignal;
pub mod waker;
pub mod writer;

/// The atomics the protocol is written against (std here; loom in the loom model).
pub(crate) mod sync {
    pub use std::sync::atomic;
}

pub use error::{Error, Result};
pub use format::{Geometry, State};
pub use reader::{ChunkInfo, Port, PortInfo, Read, View};
pub use ring::Source;
pub use writer::{Backing, ChunkMeta, PendingPort, PortParams, Writer};
