//! `bass-bridge`: a bass port across computers over Zenoh (`serve` on the capturing machine,
//! `mirror` on the reading one), and an iceoryx2 export of its chunks. docs/network.md.
//!
//! Two binaries share this library: `bass-bridge`, the installed one, and
//! `bass-bridge-faults`, a test-only build of the same code that also takes `--fault`
//! (deterministic message faults for the network suite; never installed).
#![forbid(unsafe_code)]

pub mod clock;
pub mod control;
pub mod credentials;
pub mod fault;
#[cfg(feature = "iceoryx2")]
pub mod iox;
pub mod mirror;
pub mod net;
pub mod patience;
pub mod redact;
pub mod ros2;
pub mod serve;
pub mod text;
pub mod usage;
pub mod wire;

use clap::Subcommand;

/// The commands both binaries share.
#[derive(Subcommand)]
pub enum Cmd {
    /// Publish a local port's chunks (capture side).
    Serve(serve::ServeOpts),
    /// Write a local replica port of a remote source (reading side).
    Mirror(mirror::MirrorOpts),
    /// Create a credentials file, or make one accept another machine's identity.
    Credentials(credentials::CredentialsOpts),
}

/// Logging when `BASS_LOG` is not set: ours at info; of Zenoh, errors, and the outcome of each
/// connection a peer opens to us (accepted, or refused with the reason: a wrong password, a
/// certificate), which Zenoh logs at debug.
pub const DEFAULT_LOG: &str = "info,zenoh=error,zenoh_transport::unicast::establishment::accept=debug";

/// Sets up logging (`BASS_LOG`, default [`DEFAULT_LOG`]), runs `cmd` with `faults` (none in
/// the installed binary), and exits with 1 and the error's chain on failure.
pub fn main_with(cmd: Cmd, faults: fault::Faults) -> ! {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("BASS_LOG").unwrap_or_else(|_| DEFAULT_LOG.into()),
        )
        .with_writer(redact::Stderr)
        // Colour codes only on a terminal: logs are mostly read from files and journals.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let r = match cmd {
        Cmd::Serve(o) => serve::run(o, faults),
        Cmd::Mirror(o) => mirror::run(o),
        Cmd::Credentials(o) => credentials::run(o),
    };
    match r {
        Ok(()) => std::process::exit(0),
        Err(e) => {
            eprintln!("bass-bridge: {}", redact::redact(&text::escape(&format!("{e:#}"))));
            // What the user asked for cannot be done as asked: 2, as for a bad option.
            let usage = e.chain().any(|c| c.downcast_ref::<usage::UsageError>().is_some());
            std::process::exit(if usage { 2 } else { 1 });
        }
    }
}
