//! What bass's programs (`bassd`, `bass`, `bass-bridge`, the bench) share and a client never
//! needs; the C library does not link it.
//!
//! - [`args`]: the command-line vocabulary (durations, the Acquire options and their bounds);
//! - [`limits`]: the operator's bounds on an acquisition, for bassd and the mirror;
//! - [`pacing`]: waits for a deadline within microseconds, and their stop;
//! - [`rate_estimator`]: the device-clock rate estimator (a delay-locked loop behind a
//!   stamp-quality filter), for the broker's capture and the multi-card aligner;
//! - [`instance`]: the instance lock, one process per name in a runtime directory;
//! - [`sidecar`]: the sidecar of a recording (`FILE.wav.json`), for `bass record` and the replay;
//! - [`ros2`]: the ROS 2 messages of bass (type names, definitions, CDR) for MCAP and topics;
//! - [`testsignal`]: deterministic test signals (the pattern every sample of which names its
//!   frame and channel).

#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod args;
pub mod instance;
pub mod limits;
pub mod pacing;
pub mod rate_estimator;
pub mod ros2;
pub mod sidecar;
pub mod testsignal;
