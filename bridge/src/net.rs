//! Zenoh session set-up shared by `serve` and `mirror`, and the key expressions of a source.
//!
//! Keys (with `--namespace NS`, default `bass`):
//! - `NS/<broker>/chunks`  chunk messages ([`crate::wire`]);
//! - `NS/<broker>/state`   the source port's state (JSON [`SourceState`]) on every change;
//! - `NS/<broker>/info`    queryable: the same JSON, on demand;
//! - `NS/<broker>/clock`   queryable: the source's CLOCK_MONOTONIC (8 bytes LE) for probes;
//! - `NS/<broker>/control` queryable (only with `serve --allow-control`): control messages;
//! - `NS/<broker>/alive`   liveliness token of the `serve` process.

use anyhow::{anyhow, Context, Result};
use serde::{Deserialize, Serialize};
use zenoh::Wait;

/// Zenoh options common to both sides.
#[derive(clap::Args, Clone, Debug)]
pub struct NetOpts {
    /// Zenoh configuration file (JSON5); the options below are applied on top of it.
    #[arg(long)]
    pub zenoh_config: Option<std::path::PathBuf>,
    /// Zenoh mode: peer or client.
    #[arg(long)]
    pub mode: Option<String>,
    /// Endpoint to listen on, e.g. tcp/[fd00:ba55::1]:7447 (repeatable).
    #[arg(long)]
    pub listen: Vec<String>,
    /// Endpoint to connect to, e.g. tcp/[fd00:ba55::1]:7447 (repeatable).
    #[arg(long)]
    pub connect: Vec<String>,
    /// Turn Zenoh's multicast scouting off (use explicit --listen/--connect endpoints).
    #[arg(long)]
    pub no_scouting: bool,
    /// Key prefix separating labs or set-ups sharing one network.
    #[arg(long, default_value = "bass")]
    pub namespace: String,
}

impl NetOpts {
    /// Opens a Zenoh session with these options.
    pub fn open(&self) -> Result<zenoh::Session> {
        let mut c = match &self.zenoh_config {
            Some(p) => {
                zenoh::Config::from_file(p).map_err(|e| anyhow!("zenoh config {}: {e}", p.display()))?
            }
            None => zenoh::Config::default(),
        };
        let set = |c: &mut zenoh::Config, k: &str, v: String| {
            c.insert_json5(k, &v).map_err(|e| anyhow!("zenoh config {k} = {v}: {e}"))
        };
        // A blocked put must not close the session (Zenoh's default after 5 s): during an
        // outage serve's queue drops and counts, and the session resumes when the link does.
        // Dead peers are still found by the lease (10 s by default).
        if self.zenoh_config.is_none() {
            set(
                &mut c,
                "transport/link/tx/queue/congestion_control/block/wait_before_close",
                "3600000000".into(),
            )?;
        }
        if let Some(m) = &self.mode {
            set(&mut c, "mode", format!("{m:?}"))?;
        }
        if !self.listen.is_empty() {
            set(&mut c, "listen/endpoints", serde_json::to_string(&self.listen)?)?;
        }
        if !self.connect.is_empty() {
            set(&mut c, "connect/endpoints", serde_json::to_string(&self.connect)?)?;
        }
        if self.no_scouting {
            set(&mut c, "scouting/multicast/enabled", "false".into())?;
            set(&mut c, "scouting/gossip/enabled", "false".into())?;
        }
        zenoh::open(c).wait().map_err(|e| anyhow!("{e}")).context("open the Zenoh session")
    }

    /// Key `NS/<broker>/<leaf>`.
    pub fn key(&self, broker: &str, leaf: &str) -> String {
        format!("{}/{broker}/{leaf}", self.namespace)
    }
}

/// The source port's state as `serve` sees it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SourceState {
    /// `capturing`, `stopped`, `error`, `idle`, `gone` (no port or its writer died).
    pub state: String,
    /// Error code (port format error code) when `state` is error.
    pub error_code: u32,
    /// Message.
    pub message: String,
    /// Source epoch (0 = no port).
    pub epoch: u64,
    /// Channels, rate, nFPC, nCOP.
    pub channels: u32,
    /// Hz.
    pub sample_rate: u32,
    /// nFPC.
    pub frames_per_chunk: u32,
    /// nCOP.
    pub chunks_on_port: u32,
    /// Newest frame.
    pub last_frame_index: u64,
    /// Chunks `serve` sent / dropped.
    pub chunks_sent: u64,
    /// Chunks dropped by `serve` (queue full) so far.
    pub chunks_dropped: u64,
}

/// A random instance id (not cryptographic: it only tells two `serve` runs apart).
pub fn instance_id() -> u64 {
    let t = bassclient::sys::realtime_ns();
    let mono = bassclient::sys::monotonic_ns();
    let pid = u64::from(std::process::id());
    let mut x = t ^ mono.rotate_left(17) ^ pid.rotate_left(40) ^ 0x9E37_79B9_7F4A_7C15;
    x ^= x >> 33;
    x = x.wrapping_mul(0xff51_afd7_ed55_8ccd);
    x ^= x >> 33;
    x.max(1)
}

/// Termination flag set by SIGTERM/SIGINT.
pub fn termination_flag() -> Result<std::sync::Arc<std::sync::atomic::AtomicBool>> {
    let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, flag.clone()).context("install a signal handler")?;
    }
    Ok(flag)
}
