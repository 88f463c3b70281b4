//! Zenoh session set-up shared by `serve` and `mirror`, and the key expressions of a source.
//!
//! Keys (with `--namespace NS`, default `bass`):
//! - `NS/<broker>/chunks`  chunk messages ([`crate::wire`]);
//! - `NS/<broker>/state`   the source port's state (JSON [`SourceState`]) on every change;
//! - `NS/<broker>/info`    queryable: the same JSON, on demand;
//! - `NS/<broker>/clock`   queryable: the source's CLOCK_MONOTONIC (8 bytes LE) for probes;
//! - `NS/<broker>/control` queryable (only with `serve --allow-control`): control messages;
//! - `NS/<broker>/alive/<instance>` liveliness token of the `serve` process (16 hex digits,
//!   the instance id of its chunks); older `serve`s declared `NS/<broker>/alive`.

use std::path::PathBuf;

use anyhow::{anyhow, Context, Result};
use serde::{Deserialize, Serialize};
use zenoh::Wait;

/// Zenoh options common to both sides.
#[derive(clap::Args, Clone, Debug)]
pub struct NetOpts {
    /// Zenoh configuration file (JSON5); the options below are applied on top of it.
    #[arg(long)]
    pub zenoh_config: Option<PathBuf>,
    /// Zenoh mode: peer or client.
    #[arg(long, value_parser = ["peer", "client", "router"])]
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
    /// Credentials file: this machine's identity and keys, and the public cards of the machines
    /// it trusts (docs/network.md, "Security"; made with `bass-bridge credentials`).
    #[arg(long, value_name = "FILE")]
    pub credentials: Option<PathBuf>,
    /// The identity (one that --credentials trusts) of the machine this side connects to;
    /// default: the only identity the file trusts.
    #[arg(long, value_name = "NAME")]
    pub peer: Option<String>,
    /// Run without authentication on a network: anyone who reaches an endpoint can read the
    /// audio, and feed or stop a replica. Shown in the log and the status.
    #[arg(long)]
    pub insecure: bool,
    /// Run the data path's threads, Zenoh's included (all but the shutdown watchdog), at
    /// SCHED_FIFO priority P (1..=99; 0: normal scheduling): a loaded machine then holds no
    /// chunk back (docs/network.md, "Latency"). Needs CAP_SYS_NICE or an rtprio limit, else a
    /// warning and normal scheduling.
    #[arg(long, value_name = "P", default_value_t = 0, value_parser = clap::value_parser!(i32).range(0..=99))]
    pub rt_priority: i32,
}

pub use crate::usage::UsageError;

mod config;

pub use config::{connect_endpoints, is_loopback, Prepared, CHUNK_CONGESTION, CHUNK_EXPRESS, CHUNK_PRIORITY};
use config::{for_mode, guard_namespace};

/// Who opens a session: what [`NetOpts::open`] guards.
pub enum Role {
    /// `serve`: no trusted identity may publish under the namespace here, nor on these other
    /// key expressions (`serve --ros2`'s topics, [`crate::ros2::guarded_keys`]).
    Serve(Vec<String>),
    /// `mirror`, with its `--source-identity`: only that identity may.
    Mirror(Option<String>),
}

/// An open session and the credentials it was opened with.
pub struct Opened {
    /// The session.
    pub session: zenoh::Session,
    /// The credentials, when given.
    pub credentials: Option<crate::credentials::Credentials>,
    /// A mirror's source identity (with credentials): whose signatures it requires.
    pub source_identity: Option<String>,
}

impl NetOpts {
    /// `--rt-priority`: SCHED_FIFO for the calling thread, and so for every thread made after
    /// it (Zenoh's runtimes, serve's sender threads; not the shutdown watchdog, made before);
    /// a refusal is a warning.
    fn realtime(&self) {
        if self.rt_priority == 0 {
            return;
        }
        match bassport::sys::sched::set_fifo(self.rt_priority) {
            Ok(()) => tracing::info!("real-time scheduling: SCHED_FIFO {}", self.rt_priority),
            Err(e) => tracing::warn!(
                "real-time scheduling (SCHED_FIFO {}) not permitted: {}; running at normal priority \
                 (grant CAP_SYS_NICE or an rtprio limit to enable it)",
                self.rt_priority,
                std::io::Error::from_raw_os_error(e)
            ),
        }
    }

    /// Opens a Zenoh session with these options; says at the default log level which
    /// endpoints it uses.
    pub fn open(&self, role: Role) -> Result<Opened> {
        let mut prepared = self.config()?;
        // Before the session opens: Zenoh's runtime threads, made as it opens, and the threads
        // this process makes afterwards inherit the calling thread's scheduling.
        self.realtime();
        let mut source_identity = None;
        if let Some(cred) = &prepared.credentials {
            let mut keys = vec![format!("{}/**", self.namespace)];
            let exempt = match role {
                Role::Serve(more) => {
                    keys.extend(more);
                    None
                }
                Role::Mirror(explicit) => {
                    let id = match explicit {
                        Some(n) if cred.trusted(&n).is_some() => n,
                        Some(_) => {
                            return Err(UsageError(format!(
                                "--source-identity: the credentials trust no identity of that name (they trust: {})",
                                cred.trusted_names()
                            ))
                            .into())
                        }
                        None => match (&prepared.peer, &cred.trusted[..]) {
                            (Some(p), _) => p.clone(),
                            (None, [one]) => one.name.clone(),
                            (None, _) => {
                                return Err(UsageError(format!(
                                    "the credentials trust {} identities ({}): give --source-identity NAME, \
                                     the machine whose serve feeds this mirror",
                                    cred.trusted.len(),
                                    cred.trusted_names()
                                ))
                                .into())
                            }
                        },
                    };
                    source_identity = Some(id.clone());
                    Some(id)
                }
            };
            if std::env::var_os("BASS_BRIDGE_NO_ACL").is_none() {
                guard_namespace(&mut prepared.config, &keys, cred, exempt.as_deref())?;
            }
        }
        let c = prepared.config;
        let eps = |k: &str| for_mode(&c, k).to_string();
        let session = zenoh::open(c.clone()).wait().map_err(|e| anyhow!("{e}")).with_context(|| {
            format!(
                "open the Zenoh session (listen {}, connect {})",
                eps("listen/endpoints"),
                eps("connect/endpoints")
            )
        })?;
        tracing::info!(
            zid = %session.zid(),
            listen = %eps("listen/endpoints"),
            connect = %eps("connect/endpoints"),
            "Zenoh session open"
        );
        let connect = connect_endpoints(&c);
        if !connect.is_empty() {
            watch_connections(&session, connect, "bass-bridge".into(), std::time::Duration::from_secs(3))?;
        }
        // Zenoh has read its dictionary: the in-memory file goes.
        drop(prepared.dictionary);
        Ok(Opened { session, credentials: prepared.credentials, source_identity })
    }

    /// `true` when this process runs open (`--insecure`) on a network.
    pub fn is_insecure(&self) -> bool {
        self.insecure
    }

    /// Key `NS/<broker>/<leaf>`.
    pub fn key(&self, broker: &str, leaf: &str) -> String {
        format!("{}/{broker}/{leaf}", self.namespace)
    }
}

/// A port's state as the bridge publishes it (serve's [`SourceState`], the mirror's status
/// file): the port's own states, and `gone`. In JSON the lowercase name (`"capturing"`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BridgeState {
    /// No acquisition.
    Idle,
    /// Acquire accepted, no chunk published yet.
    Starting,
    /// Chunks are being published.
    Capturing,
    /// Stopped by request.
    Stopped,
    /// The acquisition ended on an error.
    Error,
    /// No port, its writer died, or a newer acquisition replaced it.
    #[default]
    Gone,
}

impl BridgeState {
    /// The state of a port whose header says `s` (`None`: a value this version does not know).
    pub fn of_port(s: Option<bassport::State>) -> BridgeState {
        use bassport::State;
        match s {
            Some(State::Idle) => BridgeState::Idle,
            Some(State::Starting) => BridgeState::Starting,
            Some(State::Capturing) => BridgeState::Capturing,
            Some(State::Stopped) => BridgeState::Stopped,
            Some(State::Error) => BridgeState::Error,
            Some(State::Superseded) | None => BridgeState::Gone,
        }
    }
}

/// The source port's state as `serve` sees it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SourceState {
    /// `idle`, `starting`, `capturing`, `stopped`, `error`, `gone` (no port, or its writer
    /// died).
    pub state: BridgeState,
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
    /// The publishing `serve` instance (16 hex digits, as in its liveliness token and its
    /// chunks): tells apart two sources that serve one name. Empty from older `serve`s.
    #[serde(default)]
    pub instance: String,
    /// The publishing `serve`'s Zenoh id. Empty from older `serve`s.
    #[serde(default)]
    pub zid: String,
    /// Set while another `serve` instance serves the same name on this network (an error: one
    /// name, one source); says which (instance, Zenoh id when known).
    #[serde(default)]
    pub conflict: Option<String>,
    /// `serve` runs open on a network (`--insecure`): no authentication.
    #[serde(default)]
    pub insecure: bool,
    /// Remote control requests serve passed to its broker (`--allow-control`), and those it
    /// refused (identity not named, bad or replayed signature).
    #[serde(default)]
    pub control_requests: u64,
    /// See `control_requests`.
    #[serde(default)]
    pub control_refused: u64,
}

/// Checks a broker or replica name used in key expressions (`--name`, `--source`): a port
/// name (`bassport::paths::check_name`), so no `* $ # / ?` or spaces, which would make a
/// key expression match other sources.
pub fn check_key_name(option: &str, name: &str) -> Result<(), UsageError> {
    bassport::paths::check_name(name).map_err(|_| {
        UsageError(format!(
            "{option} {}: use 1 to 64 characters of A-Z a-z 0-9 . _ - (not starting with '.'): \
             no wildcard or key-expression characters such as * $ # / ?",
            crate::text::escape(&format!("{name:?}"))
        ))
    })
}

/// Checks `--namespace`: chunks of [`check_key_name`]'s characters separated by `/`.
pub fn check_namespace(ns: &str) -> Result<(), UsageError> {
    if ns.split('/').all(|c| bassport::paths::check_name(c).is_ok()) {
        return Ok(());
    }
    Err(UsageError(format!(
        "--namespace {}: use chunks of A-Z a-z 0-9 . _ - separated by /, no wildcard or key-expression \
         characters such as * $ # ?",
        crate::text::escape(&format!("{ns:?}"))
    )))
}

/// A random instance id (not cryptographic: it only tells two `serve` runs apart).
pub fn instance_id() -> u64 {
    let t = bassport::sys::realtime_ns();
    let mono = bassport::sys::monotonic_ns();
    let pid = u64::from(std::process::id());
    let mut x = t ^ mono.rotate_left(17) ^ pid.rotate_left(40) ^ 0x9E37_79B9_7F4A_7C15;
    x ^= x >> 33;
    x = x.wrapping_mul(0xff51_afd7_ed55_8ccd);
    x ^= x >> 33;
    x.max(1)
}

/// How long an orderly shutdown may take after SIGTERM/SIGINT before the process exits
/// anyway (a Zenoh call blocked on a dead link must not hold it: docs/network.md, "Outages").
pub const SHUTDOWN_DEADLINE: std::time::Duration = std::time::Duration::from_millis(800);

/// Termination flag set by SIGTERM/SIGINT. The main loop sees it and cleans up; a watchdog
/// thread ends the process [`SHUTDOWN_DEADLINE`] after the signal whatever the main loop is
/// doing, so SIGTERM ends bass-bridge within a second in every state.
pub fn termination_flag() -> Result<std::sync::Arc<std::sync::atomic::AtomicBool>> {
    let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, flag.clone()).context("install a signal handler")?;
    }
    // The watchdog blocks on the signals themselves (signal-hook's self-pipe): no polling,
    // no wake-up at all while the process runs.
    let mut signals =
        signal_hook::iterator::Signals::new([signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT])
            .context("install the shutdown watchdog's signal handler")?;
    std::thread::Builder::new()
        .name("shutdown-deadline".into())
        .spawn(move || {
            if signals.forever().next().is_none() {
                return;
            }
            std::thread::sleep(SHUTDOWN_DEADLINE);
            tracing::warn!(
                "terminated: the orderly shutdown took longer than {} ms (a Zenoh call blocked)",
                SHUTDOWN_DEADLINE.as_millis()
            );
            std::process::exit(0);
        })
        .context("start the shutdown watchdog")?;
    Ok(flag)
}

/// Why a `connect` endpoint gives no Zenoh session, found by a plain TCP connection to it:
/// nothing listens, the network does not reach it, or it answers TCP but refused the
/// session (credentials or certificates).
pub fn diagnose(endpoint: &str) -> String {
    use std::net::ToSocketAddrs;
    let ep = endpoint.split(['#', '?']).next().unwrap_or("");
    let Some((proto, addr)) = ep.split_once('/') else { return format!("{endpoint}: not an endpoint") };
    if !matches!(proto, "tcp" | "tls") {
        return format!("{endpoint}: no connection");
    }
    let addrs: Vec<_> = match addr.to_socket_addrs() {
        Ok(a) => a.collect(),
        Err(e) => return format!("{endpoint}: cannot resolve the address ({e})"),
    };
    let mut why = String::from("no address");
    for a in addrs {
        match std::net::TcpStream::connect_timeout(&a, std::time::Duration::from_secs(1)) {
            Ok(_) => {
                return format!(
                    "{endpoint}: it answers TCP but no Zenoh session came up: credentials or \
                     certificates refused, or authentication on one side only (the other side's \
                     log says which)"
                )
            }
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                why = "nothing listens there (connection refused)".into()
            }
            Err(e) => why = format!("unreachable ({e})"),
        }
    }
    format!("{endpoint}: {why}")
}

/// Watches the session's connections in a thread of its own and says at the default log
/// level when there has been none for `after` (with the reason for each `connect` endpoint,
/// [`diagnose`]), again every 30 s while it lasts, and when a connection comes up.
pub fn watch_connections(
    session: &zenoh::Session,
    connect: Vec<String>,
    what: String,
    after: std::time::Duration,
) -> Result<()> {
    use std::time::{Duration, Instant};
    let session = session.clone();
    std::thread::Builder::new()
        .name("zenoh-watch".into())
        .spawn(move || {
            let mut down_since = Some(Instant::now());
            let mut said: Option<Instant> = None;
            loop {
                std::thread::sleep(Duration::from_millis(250));
                let peers =
                    session.info().peers_zid().wait().count() + session.info().routers_zid().wait().count();
                match (peers, down_since) {
                    (0, None) => down_since = Some(Instant::now()),
                    (0, Some(t))
                        if t.elapsed() >= after
                            && said.map_or(true, |s| s.elapsed() >= Duration::from_secs(30)) =>
                    {
                        let reasons: Vec<String> = connect.iter().map(|e| diagnose(e)).collect();
                        tracing::warn!(
                            "{what}: no Zenoh connection for {:.0} s{}",
                            t.elapsed().as_secs_f64(),
                            if reasons.is_empty() {
                                String::new()
                            } else {
                                format!(": {}", reasons.join("; "))
                            }
                        );
                        said = Some(Instant::now());
                    }
                    (n, Some(_)) if n > 0 => {
                        tracing::info!("{what}: connected ({n} Zenoh peer(s))");
                        (down_since, said) = (None, None);
                    }
                    _ => {}
                }
            }
        })
        .context("start the connection watch")?;
    Ok(())
}
