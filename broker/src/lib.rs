//! bassd, the bass capture broker, as a library: the `bassd` binary and the integration tests
//! are thin layers over these modules (the `bass` tool is its own crate, cli/, which talks to
//! bassd only through the control protocol).
//!
//! - [`server`]: the control loop (socket, peer checks, requests, watchdog, signals);
//! - [`config`]: the broker's configuration (bassd's command line);
//! - [`capture`]: one acquisition — the capture thread, chunk assembly, gap filling;
//! - [`device`]: ALSA PCMs and simulated devices;
//! - [`request`]: checks an Acquire before anything running is touched (and the operator's bounds);
//! - [`policy`]: which device names a client may make the broker open;
//! - [`convert`]: device sample formats to left-justified S32;
//! - [`pins`]: superseded ports still mapped by readers, and the bound on them;
//! - [`os`]: the Linux edge on rustix (eventfd, signals, sleeps, scheduling, credentials, lock);
// `unsafe` only in `os`, the broker's Linux edge (each block with its SAFETY comment).
#![deny(unsafe_code)]

pub mod capture;
pub mod config;
pub mod convert;
pub mod device;
pub mod handoff;
#[allow(unsafe_code)] // the Linux edge
pub mod os;
pub mod pins;
pub mod policy;
pub mod request;
pub mod server;
pub mod supervise;

/// Sets up logging to stderr: `BASS_LOG` (or `RUST_LOG`) filters, `info` by default.
pub fn init_logging() {
    let filter =
        std::env::var("BASS_LOG").or_else(|_| std::env::var("RUST_LOG")).unwrap_or_else(|_| "info".into());
    let _ = tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::new(filter))
        .with_writer(std::io::stderr)
        .with_ansi(false)
        .try_init();
}
