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
}

pub use crate::usage::UsageError;

/// A Zenoh configuration checked against the security policy, with what it was made from.
pub struct Prepared {
    /// The configuration.
    pub config: zenoh::Config,
    /// The in-memory dictionary file Zenoh reads while the session opens.
    pub dictionary: Option<std::os::fd::OwnedFd>,
    /// The credentials, when given.
    pub credentials: Option<crate::credentials::Credentials>,
    /// The trusted identity this side presents itself to, if any.
    pub peer: Option<String>,
}

/// A `--zenoh-config` Zenoh refused: named by file and, where the parser says it, line and
/// column, never with its content (the parser quotes the text around the error, which may
/// be a password).
fn config_error(p: &std::path::Path, zenoh_error: &str) -> anyhow::Error {
    let mut at = String::new();
    let b = zenoh_error.as_bytes();
    for (i, w) in zenoh_error.char_indices() {
        if w.is_ascii_digit() && (i == 0 || !b[i - 1].is_ascii_alphanumeric()) {
            let num: String = zenoh_error[i..].chars().take_while(char::is_ascii_digit).collect();
            let rest = &zenoh_error[i + num.len()..];
            if let Some(col) = rest.strip_prefix(':') {
                let col: String = col.chars().take_while(char::is_ascii_digit).collect();
                if !col.is_empty() {
                    at = format!(" at line {num}, column {col}");
                    break;
                }
            }
            if zenoh_error[..i].ends_with("line ") {
                at = format!(" at line {num}");
                break;
            }
        }
    }
    UsageError(format!(
        "zenoh config {}: not a valid Zenoh configuration{at} (a syntax error or a value of the \
         wrong type; Zenoh's message is not shown, as it quotes the file, which may hold a password)",
        p.display()
    ))
    .into()
}

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

/// Messages that only the source publishes under the namespace: what [`guard_namespace`]
/// refuses from the trusted identities.
const SOURCE_ONLY: &str = r#"["put", "delete", "reply", "declare_queryable", "liveliness_token"]"#;

/// With credentials, unless `--zenoh-config` brings its own access control: the identities
/// this side accepts connections from may not put, delete, reply, or declare queryables or
/// liveliness tokens under `NS/**` here (a mirror subscribes and queries only; serve is the
/// only publisher of its keys, and a mirror checks every message's signature anyway). So an
/// authenticated peer cannot feed this process, nor others through it, nor fake a second
/// source with a token. `keys`: `NS/**` and any other key expressions only this side
/// publishes. `BASS_BRIDGE_NO_ACL` (tests only) leaves it out.
fn guard_namespace(
    c: &mut zenoh::Config,
    keys: &[String],
    cred: &crate::credentials::Credentials,
    exempt: Option<&str>,
) -> Result<()> {
    if c.get_json("access_control/enabled").is_ok_and(|j| j == "true") {
        tracing::info!("access control: the one of --zenoh-config (bass adds none)");
        return Ok(());
    }
    let users: Vec<&str> =
        cred.trusted.iter().map(|t| t.name.as_str()).filter(|n| Some(*n) != exempt).collect();
    if users.is_empty() {
        return Ok(());
    }
    let users = serde_json::to_string(&users)?;
    let keys = serde_json::to_string(keys)?;
    let acl = format!(
        r#"{{ enabled: true, default_permission: "allow",
             rules: [{{ id: "bass-source-only", messages: {SOURCE_ONLY}, flows: ["ingress"],
                        permission: "deny", key_exprs: {keys} }}],
             subjects: [{{ id: "bass-trusted", usernames: {users} }}],
             policies: [{{ rules: ["bass-source-only"], subjects: ["bass-trusted"] }}] }}"#
    );
    c.insert_json5("access_control", &acl).map_err(|e| anyhow!("access control: {e}"))?;
    Ok(())
}

/// Zenoh settings that hold a session through link outages of any length (docs/network.md,
/// "Outages"); each applies only where the user's `--zenoh-config` leaves Zenoh's default.
///
/// The root cause of the session that never recovered from an outage longer than the lease:
/// serve put its chunks with `CongestionControl::Block` and bass-bridge raised Zenoh's
/// `wait_before_close` to an hour, so on a dead link a put sat in the transport's queue for
/// an hour and the transport was never closed; with Zenoh's 5 s it is closed by that timer
/// instead of the lease, and a mirror that reconnects while that close is still being
/// processed gets a session on which nothing from serve arrives (Zenoh's routing face of the
/// new transport is torn down with the old one: "Unknown wire expr"; reproduced by removing
/// the robot's address for 6 s). Now serve puts its chunks with `CongestionControl::Drop`
/// ([`CHUNK_CONGESTION`]) and:
/// - `wait_before_drop` 50 ms (Zenoh: 1 ms): a put waits that long for room before Zenoh drops
///   it, so on a slow link serve's own bounded queue fills and serve counts its drops (the
///   SOURCE_LOSS mark); what Zenoh drops shows as a sequence gap at the mirror;
/// - lease 2 s (keep-alives every 0.5 s; Zenoh: 10 s): a dead link's transport is closed on
///   both sides 2 s after it died, so a link that returns later is a fresh connection, not a
///   TCP connection waiting out its retransmission back-off;
/// - connect retries every 0.25 s to 1 s (Zenoh: 1 s to 4 s): the link is back in use at
///   most about a second after it returns, whatever the outage's length.
const OUTAGE_SETTINGS: &[(&str, &str)] = &[
    ("transport/link/tx/queue/congestion_control/drop/wait_before_drop", "50000"),
    ("transport/link/tx/lease", "2000"),
    ("connect/retry", "{period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2}"),
];

/// How serve's chunk publisher behaves when the link cannot take more: see [`OUTAGE_SETTINGS`].
pub const CHUNK_CONGESTION: zenoh::qos::CongestionControl = zenoh::qos::CongestionControl::Drop;

impl NetOpts {
    /// The Zenoh configuration these options make, checked against the security policy:
    /// without authentication only loopback is allowed, unless `--insecure`.
    pub fn config(&self) -> Result<Prepared> {
        let mut c = match &self.zenoh_config {
            Some(p) => zenoh::Config::from_file(p).map_err(|e| config_error(p, &e.to_string()))?,
            None => zenoh::Config::default(),
        };
        let set = |c: &mut zenoh::Config, k: &str, v: String| {
            c.insert_json5(k, &v).map_err(|e| anyhow!("zenoh config {k} = {v}: {e}"))
        };
        for (k, v) in OUTAGE_SETTINGS {
            if self.zenoh_config.is_none() || c.get_json(k).is_ok_and(|j| j == default_json(k)) {
                set(&mut c, k, (*v).into())?;
            }
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
        let mut prepared =
            Prepared { config: zenoh::Config::default(), dictionary: None, credentials: None, peer: None };
        if let Some(path) = &self.credentials {
            let cred = crate::credentials::Credentials::load(path)?;
            crate::redact::add(cred.secrets());
            let file = path.display();
            let peer = match &self.peer {
                Some(p) if cred.trusted(p).is_some() => Some(p.clone()),
                // Not echoed: a value given by mistake here may be a secret.
                Some(_) => {
                    return Err(UsageError(format!(
                        "--peer: {file} trusts no identity of that name (it trusts: {})",
                        cred.trusted_names()
                    ))
                    .into())
                }
                None if cred.trusted.len() == 1 => Some(cred.trusted[0].name.clone()),
                None => None,
            };
            let connects = !connect_endpoints(&c).is_empty();
            match (&peer, connects) {
                (Some(p), _) => {
                    let pw = cred.pair_password(&cred.user, p).ok_or_else(|| {
                        anyhow!("{file}: no key agreement with {p:?} (a degenerate public key in its card)")
                    })?;
                    set(&mut c, "transport/auth/usrpwd/user", serde_json::to_string(&cred.user)?)?;
                    set(&mut c, "transport/auth/usrpwd/password", serde_json::to_string(&pw)?)?;
                }
                (None, true) if cred.trusted.is_empty() => {
                    return Err(UsageError(format!(
                        "{file} trusts no identity: trust the public card of the machine this side connects \
                         to (`bass-bridge credentials {file} --trust OTHER.pub`)"
                    ))
                    .into())
                }
                (None, true) => {
                    return Err(UsageError(format!(
                        "{file} trusts {} identities ({}): give --peer NAME, the one this side connects to",
                        cred.trusted.len(),
                        cred.trusted_names()
                    ))
                    .into())
                }
                (None, false) => {}
            }
            if !cred.trusted.is_empty() {
                // Zenoh's dictionary, made here and held in memory only: Zenoh reads it once
                // while the session opens ([`Prepared`] keeps it until then).
                let fd = rustix::fs::memfd_create("bass-bridge-dictionary", rustix::fs::MemfdFlags::CLOEXEC)
                    .context("memfd_create for the Zenoh dictionary")?;
                let dict = cred.zenoh_dictionary();
                let mut f = std::fs::File::from(fd);
                std::io::Write::write_all(&mut f, dict.as_bytes()).context("write the Zenoh dictionary")?;
                let fd = std::os::fd::OwnedFd::from(f);
                let path = format!("/proc/self/fd/{}", std::os::fd::AsRawFd::as_raw_fd(&fd));
                set(&mut c, "transport/auth/usrpwd/dictionary_file", serde_json::to_string(&path)?)?;
                prepared.dictionary = Some(fd);
            }
            prepared.peer = peer;
            prepared.credentials = Some(cred);
        }
        if let Ok(j) = c.get_json("transport/auth/usrpwd/password") {
            if let Ok(Some(pw)) = serde_json::from_str::<Option<String>>(&j) {
                crate::redact::add([pw]);
            }
        }
        let exposure = exposure(&c);
        let auth = match &prepared.credentials {
            Some(cred) => Some(format!(
                "bass credentials, as {:?}{}; trusting {}",
                cred.user,
                prepared.peer.as_ref().map(|p| format!(" to {p:?}")).unwrap_or_default(),
                cred.trusted_names()
            )),
            None => authentication(&c),
        };
        match (exposure.is_empty(), auth, self.insecure) {
            (_, Some(how), _) => tracing::info!("authentication: {how}"),
            (true, None, _) => tracing::info!("loopback only: no authentication needed"),
            (false, None, true) => tracing::warn!(
                "INSECURE: no authentication on {}: anyone who reaches it can read the audio, and \
                 feed or stop a replica (--insecure)",
                exposure.join(", ")
            ),
            (false, None, false) => {
                return Err(UsageError(format!(
                    "refusing to run without authentication on {}: anyone who reaches it could read \
                     the audio, and feed or stop a replica. Give --credentials FILE (made with \
                     `bass-bridge credentials`; docs/network.md, \"Security\"), a --zenoh-config \
                     with TLS client certificates or user/password, or --insecure to run open anyway",
                    exposure.join(", ")
                ))
                .into())
            }
        }
        prepared.config = c;
        Ok(prepared)
    }

    /// Opens a Zenoh session with these options; says at the default log level which
    /// endpoints it uses.
    pub fn open(&self, role: Role) -> Result<Opened> {
        let mut prepared = self.config()?;
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
    // no wake-up at all while the process runs (it polled the flag 50 times a second).
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

/// Zenoh's own default of configuration key `k`, as JSON.
fn default_json(k: &str) -> String {
    zenoh::Config::default().get_json(k).unwrap_or_default()
}

/// A configuration value that may depend on the mode (`{router: .., peer: .., client: ..}`),
/// for the session's mode.
fn for_mode(c: &zenoh::Config, k: &str) -> serde_json::Value {
    let v: serde_json::Value =
        c.get_json(k).ok().and_then(|j| serde_json::from_str(&j).ok()).unwrap_or_default();
    let mode: String = c
        .get_json("mode")
        .ok()
        .and_then(|j| serde_json::from_str::<Option<String>>(&j).ok().flatten())
        .unwrap_or_else(|| "peer".into());
    match v {
        serde_json::Value::Object(mut m) if m.contains_key(&mode) => m.remove(&mode).unwrap_or_default(),
        v => v,
    }
}

fn endpoints(c: &zenoh::Config) -> Vec<String> {
    let mut out = Vec::new();
    for k in ["listen/endpoints", "connect/endpoints"] {
        if let serde_json::Value::Array(a) = for_mode(c, k) {
            out.extend(a.into_iter().filter_map(|e| e.as_str().map(str::to_owned)));
        }
    }
    out
}

/// `true` for an endpoint no other computer can reach: a Unix socket, or TCP/UDP/TLS/QUIC on a
/// loopback address.
pub fn is_loopback(endpoint: &str) -> bool {
    let ep = endpoint.split(['#', '?']).next().unwrap_or("");
    let Some((proto, addr)) = ep.split_once('/') else { return false };
    if proto.starts_with("unixsock") {
        return true;
    }
    let host = match addr.rsplit_once(':') {
        Some((h, _port)) => h.trim_start_matches('[').trim_end_matches(']'),
        None => return false,
    };
    host == "localhost" || host.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

/// What of this configuration other computers can reach: non-loopback endpoints, multicast
/// scouting. Empty: loopback only.
fn exposure(c: &zenoh::Config) -> Vec<String> {
    let mut out: Vec<String> = endpoints(c).into_iter().filter(|e| !is_loopback(e)).collect();
    if for_mode(c, "scouting/multicast/enabled") != serde_json::Value::Bool(false) {
        out.push("multicast scouting".into());
    }
    out
}

/// How this configuration authenticates the peers that connect to it, if it does: Zenoh
/// user/password with a dictionary of accepted identities, or TLS with client certificates
/// on every endpoint.
fn authentication(c: &zenoh::Config) -> Option<String> {
    let get =
        |k: &str| c.get_json(k).ok().and_then(|j| serde_json::from_str::<Option<String>>(&j).ok().flatten());
    if let (Some(user), Some(_), Some(_)) = (
        get("transport/auth/usrpwd/user"),
        get("transport/auth/usrpwd/password"),
        get("transport/auth/usrpwd/dictionary_file"),
    ) {
        return Some(format!("Zenoh user/password, as {user:?}"));
    }
    let mtls = c.get_json("transport/link/tls/enable_mtls").is_ok_and(|j| j == "true");
    let eps = endpoints(c);
    (mtls && !eps.is_empty() && eps.iter().all(|e| e.starts_with("tls/") || is_loopback(e)))
        .then(|| "TLS with client certificates".to_string())
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

/// The `connect` endpoints of a configuration, for the session's mode.
pub fn connect_endpoints(c: &zenoh::Config) -> Vec<String> {
    match for_mode(c, "connect/endpoints") {
        serde_json::Value::Array(a) => a.into_iter().filter_map(|e| e.as_str().map(str::to_owned)).collect(),
        _ => Vec::new(),
    }
}
