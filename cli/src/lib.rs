//! `bass`, the command-line tool of the bass broker, as a library (the binary and the
//! integration tests are thin layers over it). It talks to `bassd` only through the control
//! protocol and the port, both in `bassport`; the Acquire options it shares with `bassd`
//! are `basskit::args::AcquireArgs`.
//!
//! - [`bass`]: the `bass` command line and its dispatch (devices, acquire, stop, status,
//!   completions);
//! - [`blocks`]: `bass blocks`, the BASC loop with one line (or JSON object) per block;
//! - [`follow`]: opening a port and following it across acquisitions (new epochs);
//! - [`meter`]: `bass meter`, the live level meter;
//! - [`plot`]: `bass plot`, PNG pictures of a recording or of the port;
//! - [`record`]: `bass record FILE.wav` with its timestamp sidecar, and `--check`;
//! - [`wav`]: the WAV writer, header parser and repair of `bass record`;
//! - [`lsl`]: `bass lsl`, the port as a Lab Streaming Layer stream with loss markers;
//! - [`labstream`]: what `bass lsl` and an XDF recording say alike (desc, stamps, markers);
//! - [`exit`]: the documented exit codes and how errors map onto them;
//! - [`out`]: stdout and stderr as Unix tools use them (a closed pipe ends a command quietly).
#![forbid(unsafe_code)]

pub mod alignment;
pub mod bass;
pub mod blocks;
pub mod exit;
pub mod follow;
pub mod labstream;
pub mod lsl;
pub mod meter;
pub mod out;
pub mod plot;
pub mod record;
pub mod wav;
