//! bassport: the shared audio port of the bass broker and its control protocol — everything a
//! client needs. Rust programs depend on this crate alone; the C library (`libbassclient`,
//! crate `bassclient`) wraps it; what only bass's own programs share is in `basskit`.
//!
//! - [`format`]: the port format (the one definition of the shared layout);
//! - [`ring`]: the lock-free one-writer / many-readers window protocol;
//! - [`writer::Writer`]: creates a port and publishes chunks (used by `bassd`, simulators, tests);
//! - [`reader::Port`]: opens a port read-only; `get_audio_data` is the formal
//!   `getAudioData` algorithm of the BASS documentation;
//! - [`stream`]: callback streams (a closure per block, with its first frame, loss, flags and
//!   timestamps), on the caller's thread or bass's own;
//! - [`access`]: what a client is told when the system refuses it a broker's socket or port;
//! - [`control`]: the broker's control protocol and its [`control::Client`].
//!
//! The main paths, each with a runnable example: open a port, wait, read
//! ([`Port::open`], [`Port::wait`], [`Port::get_audio_data`], [`Port::chunk_info`]); create a
//! writer and publish ([`Writer::create_at`], [`Writer::publish`]); ask a broker to acquire
//! ([`control::Client`]).

#![warn(missing_docs)]
// `unsafe` only where the port meets the machine, each block with its SAFETY comment: the
// race-free copy out of the shared window (`ring`), the mapping (`shm`), the SIGBUS guard
// (`sigbus`) and the libc calls rustix does not wrap (`sys::sched`, `sys::peer`).
#![deny(unsafe_code)]

pub mod access;
pub mod control;
pub mod error;
pub mod format;
pub mod memfd;
pub mod paths;
pub mod portfile;
pub mod reader;
#[allow(unsafe_code)] // the OS edge (see the crate root)
pub mod ring;
#[allow(unsafe_code)] // the OS edge (see the crate root)
mod shm;
#[allow(unsafe_code)] // the OS edge (see the crate root)
pub mod sigbus;
pub mod stream;
pub mod sys;
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
