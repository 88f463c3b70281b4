//! The Zenoh configuration [`NetOpts`] make, and the security policy it is checked against:
//! without authentication only loopback, unless `--insecure`.

use anyhow::{anyhow, Context, Result};

use super::NetOpts;
use crate::usage::UsageError;

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
pub(super) fn guard_namespace(
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
/// They go with serve putting its chunks with `CongestionControl::Drop` ([`CHUNK_CONGESTION`])
/// and Zenoh's own `wait_before_close` (5 s): a put waits at most `wait_before_drop` on a dead
/// link, so the dead link's transport is closed and a link that returns gets a fresh one. (With
/// `CongestionControl::Block` and a long `wait_before_close`, a put sits in the queue of a
/// dead link's transport, which is then never closed; and a mirror reconnecting while a
/// transport is being closed can get a session on which nothing from serve arrives.)
/// - `wait_before_drop` 50 ms (Zenoh: 1 ms): a put waits that long for room before Zenoh drops
///   it, so on a slow link serve's own bounded queue fills and serve counts its drops once a
///   chunk is [`crate::patience::LIVE_PATIENCE`] behind (the SOURCE_LOSS mark); what Zenoh
///   drops shows as a sequence gap at the mirror;
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

/// Chunks go out at once, not batched with what follows them (Zenoh's express publication):
/// a chunk's delay is its own, not the batch's (docs/network.md, "Latency").
pub const CHUNK_EXPRESS: bool = true;

/// Chunks are the link's real-time traffic: they pass the control and clock messages queued
/// beside them.
pub const CHUNK_PRIORITY: zenoh::qos::Priority = zenoh::qos::Priority::RealTime;

impl NetOpts {
    /// The Zenoh configuration these options make, checked against the security policy:
    /// without authentication only loopback is allowed, unless `--insecure`.
    pub fn config(&self) -> Result<Prepared> {
        let mut c = self.zenoh_options()?;
        let mut prepared =
            Prepared { config: zenoh::Config::default(), dictionary: None, credentials: None, peer: None };
        if let Some(path) = &self.credentials {
            self.add_credentials(&mut c, path, &mut prepared)?;
        }
        if let Ok(j) = c.get_json("transport/auth/usrpwd/password") {
            if let Ok(Some(pw)) = serde_json::from_str::<Option<String>>(&j) {
                crate::redact::add([pw]);
            }
        }
        check_policy(&c, &prepared, self.insecure)?;
        prepared.config = c;
        Ok(prepared)
    }

    /// `--zenoh-config` (or Zenoh's defaults), the outage settings where it leaves Zenoh's
    /// defaults, and the options on top.
    fn zenoh_options(&self) -> Result<zenoh::Config> {
        let mut c = match &self.zenoh_config {
            Some(p) => zenoh::Config::from_file(p).map_err(|e| config_error(p, &e.to_string()))?,
            None => zenoh::Config::default(),
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
        Ok(c)
    }

    /// `--credentials`: the user/password towards the peer (`--peer`, or the only trusted
    /// identity), the dictionary of the trusted identities, the credentials kept in `prepared`.
    fn add_credentials(
        &self,
        c: &mut zenoh::Config,
        path: &std::path::Path,
        prepared: &mut Prepared,
    ) -> Result<()> {
        let cred = crate::credentials::Credentials::load(path)?;
        crate::redact::add(cred.secrets());
        let file = path.display();
        let peer = self.peer_of(&cred, &file)?;
        let connects = !connect_endpoints(c).is_empty();
        match (&peer, connects) {
            (Some(p), _) => {
                let pw = cred.pair_password(&cred.user, p).ok_or_else(|| {
                    anyhow!("{file}: no key agreement with {p:?} (a degenerate public key in its card)")
                })?;
                set(c, "transport/auth/usrpwd/user", serde_json::to_string(&cred.user)?)?;
                set(c, "transport/auth/usrpwd/password", serde_json::to_string(&pw)?)?;
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
            prepared.dictionary = Some(dictionary(c, &cred)?);
        }
        prepared.peer = peer;
        prepared.credentials = Some(cred);
        Ok(())
    }

    /// The trusted identity this side presents itself to: `--peer`, or the only one `file`
    /// trusts.
    fn peer_of(
        &self,
        cred: &crate::credentials::Credentials,
        file: &std::path::Display,
    ) -> Result<Option<String>> {
        Ok(match &self.peer {
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
        })
    }
}

/// Zenoh's dictionary of the trusted identities, made here and held in memory only: Zenoh
/// reads it once while the session opens ([`Prepared`] keeps it until then).
fn dictionary(c: &mut zenoh::Config, cred: &crate::credentials::Credentials) -> Result<std::os::fd::OwnedFd> {
    let fd = rustix::fs::memfd_create("bass-bridge-dictionary", rustix::fs::MemfdFlags::CLOEXEC)
        .context("memfd_create for the Zenoh dictionary")?;
    let dict = cred.zenoh_dictionary();
    let mut f = std::fs::File::from(fd);
    std::io::Write::write_all(&mut f, dict.as_bytes()).context("write the Zenoh dictionary")?;
    let fd = std::os::fd::OwnedFd::from(f);
    let path = format!("/proc/self/fd/{}", std::os::fd::AsRawFd::as_raw_fd(&fd));
    set(c, "transport/auth/usrpwd/dictionary_file", serde_json::to_string(&path)?)?;
    Ok(fd)
}

/// Sets configuration key `k` to the JSON5 value `v`.
fn set(c: &mut zenoh::Config, k: &str, v: String) -> Result<()> {
    c.insert_json5(k, &v).map_err(|e| anyhow!("zenoh config {k} = {v}: {e}"))
}

/// The security policy: a configuration that other computers can reach needs authentication
/// (bass credentials, Zenoh user/password or TLS client certificates), or `--insecure`. Says
/// at the default log level which it is.
fn check_policy(c: &zenoh::Config, prepared: &Prepared, insecure: bool) -> Result<()> {
    let exposure = exposure(c);
    let auth = match &prepared.credentials {
        Some(cred) => Some(format!(
            "bass credentials, as {:?}{}; trusting {}",
            cred.user,
            prepared.peer.as_ref().map(|p| format!(" to {p:?}")).unwrap_or_default(),
            cred.trusted_names()
        )),
        None => authentication(c),
    };
    match (exposure.is_empty(), auth, insecure) {
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
    Ok(())
}

/// Zenoh's own default of configuration key `k`, as JSON.
fn default_json(k: &str) -> String {
    zenoh::Config::default().get_json(k).unwrap_or_default()
}

/// A configuration value that may depend on the mode (`{router: .., peer: .., client: ..}`),
/// for the session's mode.
pub(super) fn for_mode(c: &zenoh::Config, k: &str) -> serde_json::Value {
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

/// The `connect` endpoints of a configuration, for the session's mode.
pub fn connect_endpoints(c: &zenoh::Config) -> Vec<String> {
    match for_mode(c, "connect/endpoints") {
        serde_json::Value::Array(a) => a.into_iter().filter_map(|e| e.as_str().map(str::to_owned)).collect(),
        _ => Vec::new(),
    }
}
