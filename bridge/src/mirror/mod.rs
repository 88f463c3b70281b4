//! `bass-bridge mirror`: subscribes to one source and writes a local replica port at the
//! source's frame indices, so every local client reads remote audio unchanged.
//!
//! The message handling (bounds, followed instance, rate limits, gaps, states) is
//! [`core::Core`], pure and tested in-process; this module wires it to Zenoh, takes the
//! replica's name (the instance lock, as bassd does: `basskit::instance`), serves the
//! replica's control socket ([`crate::control`]), writes the status file and logs.
//!
//! - source unreachable (liveliness lost, or silent) longer than `--timeout`, or the source
//!   port in error or gone: the replica shows a device error; data brings it back;
//! - SIGTERM/SIGINT: the replica port, the control socket and the lock are removed.

pub mod bounds;
pub mod core;
mod replica;
pub mod status;

use std::sync::atomic::Ordering;
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use anyhow::{anyhow, Result};
use basskit::instance::{Instance, InstanceError};
use bassport::sys::monotonic_ns;
use zenoh::pubsub::Subscriber;
use zenoh::sample::SampleKind;
use zenoh::Wait;

use self::bounds::Bounds;
use self::core::{Core, LogLimit, MirrorStatus};
use basskit::args::parse_seconds;

use crate::clock::ClockEstimator;
use crate::net::{self, NetOpts, UsageError};

/// A group given by number, or by name as /etc/group lists it.
fn parse_group(s: &str) -> std::result::Result<u32, String> {
    if let Ok(gid) = s.parse::<u32>() {
        return Ok(gid);
    }
    let groups = std::fs::read_to_string("/etc/group").map_err(|e| format!("/etc/group: {e}"))?;
    groups
        .lines()
        .filter_map(|l| {
            let mut f = l.split(':');
            let name = f.next()?;
            let gid = f.nth(1)?.parse::<u32>().ok()?;
            (name == s).then_some(gid)
        })
        .next()
        .ok_or_else(|| format!("no group {s:?} in /etc/group (give its name or number)"))
}

/// Options of `mirror`.
#[derive(clap::Args, Debug)]
pub struct MirrorOpts {
    /// Source broker name (as given to `serve --name`).
    #[arg(long, default_value = "default")]
    pub source: String,
    /// Name of the local replica port (default `<host>-<source>`).
    #[arg(long)]
    pub name: Option<String>,
    /// Seconds without the source (liveliness or any message) before the replica shows an error.
    #[arg(long, default_value = "2", value_parser = parse_seconds)]
    pub timeout: f64,
    /// Write the mirror's counters and clock estimate as JSON to this file, once a second.
    #[arg(long)]
    pub status_file: Option<std::path::PathBuf>,
    /// Give the replica port to this group (name or number): its members read it, as they
    /// read the ports of `bassd --group` (the mirror must be a member of the group, e.g.
    /// systemd's Group=, or root with CAP_CHOWN). Default: the mirror's own group.
    #[arg(long, value_name = "GROUP", value_parser = parse_group)]
    pub group: Option<u32>,
    /// Seconds between clock probes.
    #[arg(long, default_value = "0.5", value_parser = parse_seconds)]
    pub probe_interval: f64,
    /// The identity (of --credentials) whose signature every chunk, state, clock answer and
    /// control reply must carry; default: --peer, or the only identity the file trusts.
    #[arg(long, value_name = "NAME")]
    pub source_identity: Option<String>,
    #[command(flatten)]
    pub bounds: Bounds,
    #[command(flatten)]
    pub net: NetOpts,
}

/// What the subscribers other than the chunks' report to the main loop.
enum Event {
    State(Vec<u8>),
    /// A state message without the source's signature.
    Forged,
    /// A liveliness token of the source appeared or went (its serve instance, if it says).
    Alive(Option<u64>, bool),
}

fn lock(core: &Mutex<Core>) -> MutexGuard<'_, Core> {
    core.lock().unwrap_or_else(|e| e.into_inner())
}

/// Takes the replica's name; a name held by a live broker or mirror is a usage error (exit 2)
/// naming the holder.
fn take_name(name: &str) -> Result<Instance> {
    Instance::take(name).map_err(|e| match e {
        InstanceError::Held { name, holder, lock, .. } => UsageError(format!(
            "the name {name:?} is taken by a running bass broker or mirror ({holder}, lock {}): \
             give this mirror another --name",
            lock.display()
        ))
        .into(),
        InstanceError::SystemName { .. } | InstanceError::Name(_) => UsageError(e.to_string()).into(),
        e => anyhow!(e),
    })
}

/// Runs `mirror` until SIGTERM/SIGINT.
pub fn run(o: MirrorOpts) -> Result<()> {
    net::check_key_name("--source", &o.source)?;
    net::check_namespace(&o.net.namespace)?;
    if let Some(n) = &o.name {
        net::check_key_name("--name", n)?;
    }
    let term = net::termination_flag()?;
    let name = o.name.clone().unwrap_or_else(|| format!("{}-{}", hostname(), o.source));
    let instance = take_name(&name)?;
    if instance.removed_stale_socket {
        tracing::warn!(
            "removed the stale control socket {} left by a process that died",
            instance.socket_path().display()
        );
    }
    let r = run_named(&o, &name, &instance, term);
    // Whatever ended it (a signal, or an error at start-up): the name is given back whole.
    instance.remove_socket();
    instance.remove_lock();
    r
}

/// `mirror` once its name is taken.
fn run_named(
    o: &MirrorOpts,
    name: &str,
    instance: &Instance,
    term: Arc<std::sync::atomic::AtomicBool>,
) -> Result<()> {
    let opened = o.net.open(net::Role::Mirror(o.source_identity.clone()))?;
    let session = opened.session;
    let cred = opened.credentials.map(Arc::new);
    // With credentials: the source's public identity, whose signature everything must carry.
    let source_id = match (&cred, &opened.source_identity) {
        (Some(c), Some(n)) => c.trusted(n).cloned().map(Arc::new),
        _ => None,
    };
    let probe_key = match (&cred, &source_id) {
        (Some(c), Some(id)) => c
            .pair_secret(&id.name, &c.user, "clock")
            .map(|key| crate::clock::ProbeKey { user: c.user.clone(), key }),
        _ => None,
    };
    let clock = Arc::new(ClockEstimator::spawn(
        &session,
        o.net.key(&o.source, "clock"),
        Duration::from_secs_f64(o.probe_interval.max(0.01)),
        probe_key,
    )?);
    let st = MirrorStatus {
        replica: name.to_owned(),
        source: o.source.clone(),
        insecure: o.net.insecure,
        source_identity: source_id.as_ref().map(|i| i.name.clone()).unwrap_or_default(),
        ..Default::default()
    };
    let mut new_core = Core::new(instance.port_path(), o.bounds.clone(), st, monotonic_ns());
    new_core.group = o.group;
    let core = Arc::new(Mutex::new(new_core));
    let chunks = subscribe_chunks(&session, o, &core, &clock, source_id.clone())?;
    let (tx, rx) = channel::<Event>();
    let _state = subscribe_state(&session, o, source_id.clone(), tx.clone())?;
    let _alive = subscribe_alive(&session, o, tx)?;

    let signer = match (&cred, &source_id) {
        (Some(c), Some(id)) => {
            Some(Arc::new(crate::control::Signer { credentials: c.clone(), source: id.name.clone() }))
        }
        _ => None,
    };
    let status_core = core.clone();
    let forwarder = crate::control::spawn_forwarder(
        &session,
        o.net.key(&o.source, "control"),
        signer,
        instance,
        term.clone(),
        Arc::new(move || lock(&status_core).control_status(monotonic_ns())),
    )?;
    tracing::info!(replica = %name, source = %o.source, "mirroring");
    follow(o, &core, &clock, &rx, &term, source_id.is_some());
    drop(chunks);
    lock(&core).remove();
    forwarder.stop();
    tracing::info!("mirror: terminated");
    Ok(())
}

/// The chunk subscriber: each chunk (with `source_id`, only one it signed) goes to the core
/// in the subscriber's callback, stamped with the clock offset, and its timestamps to the
/// clock estimator.
fn subscribe_chunks(
    session: &zenoh::Session,
    o: &MirrorOpts,
    core: &Arc<Mutex<Core>>,
    clock: &Arc<ClockEstimator>,
    source_id: Option<Arc<crate::credentials::Identity>>,
) -> Result<Subscriber<()>> {
    let (chunk_core, chunk_clock) = (core.clone(), clock.clone());
    let (chunk_key, chunk_id) = (o.net.key(&o.source, "chunks"), source_id);
    session
        .declare_subscriber(chunk_key.clone())
        .callback(move |s| {
            let clock = chunk_clock.map();
            let bytes = s.payload().to_bytes();
            if let Some(id) = &chunk_id {
                let sig = s.attachment().map(|a| a.to_bytes()).unwrap_or_default();
                if !id.verify(&chunk_key, &bytes, &sig) {
                    lock(&chunk_core).on_forged("chunks", monotonic_ns());
                    return;
                }
            }
            let mut c = lock(&chunk_core);
            c.on_message(&bytes, monotonic_ns(), clock);
            if let Some((source, local)) = c.take_stamp() {
                chunk_clock.observe_chunk(source, local);
            }
        })
        .wait()
        .map_err(|e| anyhow!("subscribe to chunks: {e}"))
}

/// The state subscriber: each state message to the main loop, as [`Event::Forged`] if
/// `source_id` did not sign it.
fn subscribe_state(
    session: &zenoh::Session,
    o: &MirrorOpts,
    source_id: Option<Arc<crate::credentials::Identity>>,
    state_tx: Sender<Event>,
) -> Result<Subscriber<()>> {
    let (state_key, state_id) = (o.net.key(&o.source, "state"), source_id);
    session
        .declare_subscriber(state_key.clone())
        .callback(move |s| {
            let bytes = s.payload().to_bytes().into_owned();
            let signed = state_id.as_ref().map_or(true, |id| {
                id.verify(&state_key, &bytes, &s.attachment().map(|a| a.to_bytes()).unwrap_or_default())
            });
            let _ = state_tx.send(if signed { Event::State(bytes) } else { Event::Forged });
        })
        .wait()
        .map_err(|e| anyhow!("subscribe to state: {e}"))
}

/// The liveliness subscriber: the source's tokens appearing and going, to the main loop.
fn subscribe_alive(session: &zenoh::Session, o: &MirrorOpts, tx: Sender<Event>) -> Result<Subscriber<()>> {
    // serve's token is `NS/<broker>/alive/<instance>` (an older serve's: `NS/<broker>/alive`).
    let alive_key = o.net.key(&o.source, "alive");
    session
        .liveliness()
        .declare_subscriber(format!("{alive_key}/**"))
        .history(true)
        .callback(move |s| {
            let leaf = s.key_expr().as_str().strip_prefix(alive_key.as_str()).unwrap_or_default();
            let instance = leaf.strip_prefix('/').and_then(|h| u64::from_str_radix(h, 16).ok());
            let _ = tx.send(Event::Alive(instance, s.kind() == SampleKind::Put));
        })
        .wait()
        .map_err(|e| anyhow!("liveliness subscriber: {e}"))
}

/// Where this mirror looks for the source, for the warnings.
fn endpoints(net: &NetOpts) -> String {
    match (&net.connect[..], &net.listen[..], &net.zenoh_config) {
        ([], [], Some(p)) => format!("endpoints of {}", p.display()),
        ([], [], None) => "Zenoh's default endpoints and scouting".to_owned(),
        ([], listen, _) => format!("listening on {}", listen.join(", ")),
        (connect, _, _) => format!("connecting to {}", connect.join(", ")),
    }
}

/// The main loop until `term`: the events to the core, its tick (the source's timeout) every
/// 100 ms at most, the status once a second. `signed`: with credentials.
fn follow(
    o: &MirrorOpts,
    core: &Mutex<Core>,
    clock: &ClockEstimator,
    rx: &Receiver<Event>,
    term: &std::sync::atomic::AtomicBool,
    signed: bool,
) {
    let timeout_ns = (o.timeout * 1e9) as u64;
    let endpoints = endpoints(&o.net);
    // The source's live tokens: the source is alive while there is one.
    let mut tokens = std::collections::BTreeSet::new();
    let mut last_status = 0u64;
    let mut status_log = LogLimit::default();
    while !term.load(Ordering::Relaxed) {
        let ev = rx.recv_timeout(Duration::from_millis(100));
        let now = monotonic_ns();
        let mut c = lock(core);
        match ev {
            Ok(Event::State(bytes)) => c.on_state(&bytes, now),
            Ok(Event::Forged) => c.on_forged("state", now),
            // With credentials a token proves nothing (anyone admitted can declare one): only
            // the followed instance's, known from its signed messages, is taken.
            Ok(Event::Alive(instance, _))
                if signed && (instance.is_none() || instance != c.followed_instance()) =>
            {
                tracing::debug!(instance, "liveliness token of an instance not (yet) heard signed: ignored");
            }
            Ok(Event::Alive(instance, a)) => on_alive(&mut c, &mut tokens, instance, a, now, &o.source),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        if let Some(why) = c.tick(now, timeout_ns, !tokens.is_empty()) {
            tracing::warn!("source {:?} ({endpoints}): {why}", o.source);
        }
        if now.saturating_sub(last_status) >= 1_000_000_000 {
            last_status = now;
            report_status(o, core, clock, c, now, &mut status_log);
        }
    }
}

/// A token of the source's `instance` appeared (`a`) or went: kept in `tokens`, told to the
/// core, logged.
fn on_alive(
    c: &mut Core,
    tokens: &mut std::collections::BTreeSet<u64>,
    instance: Option<u64>,
    a: bool,
    now: u64,
    source: &str,
) {
    // Bounded: a peer declaring many tokens cannot grow it past the cap.
    let id = instance.unwrap_or(0);
    if a && tokens.len() < 64 {
        tokens.insert(id);
    } else if !a {
        tokens.remove(&id);
    }
    if a {
        c.last_heard_ns = now;
    }
    if let Some(i) = instance {
        c.on_token(i, a);
    }
    let instance = instance.map(|i| format!("{i:016x}")).unwrap_or_default();
    tracing::info!(alive = a, source = %source, instance, "source liveliness");
}

/// The clock estimate into the status, and the status to `--status-file`: `c` (the core's
/// lock) is released before the file is written.
fn report_status(
    o: &MirrorOpts,
    core: &Mutex<Core>,
    clock: &ClockEstimator,
    mut c: MutexGuard<'_, Core>,
    now: u64,
    status_log: &mut LogLimit,
) {
    let (off, unc) = clock.estimate();
    c.st.clock_offset_ns = off;
    c.st.clock_uncertainty_ns = unc;
    c.st.clock_drift_ppm = clock.drift_ppm();
    c.st.clock_replies_refused = clock.refused();
    c.refresh();
    let st = c.st.clone();
    drop(c);
    // Written without the lock: the chunk subscriber never waits for the disk.
    if let Some(p) = &o.status_file {
        if let Err(e) = write_status(p, &st) {
            lock(core).st.status_write_failures += 1;
            if let Some(n) = status_log.allow(now) {
                let more = if n > 0 { format!(" ({n} more failures not logged)") } else { String::new() };
                tracing::warn!("status file {}: {e:#}{more}", p.display());
            }
        }
    }
}

fn write_status(p: &std::path::Path, st: &MirrorStatus) -> Result<()> {
    let tmp = p.with_extension("tmp");
    std::fs::write(&tmp, serde_json::to_vec_pretty(st)?)?;
    std::fs::rename(&tmp, p)?;
    Ok(())
}

fn hostname() -> String {
    let h =
        std::fs::read_to_string("/proc/sys/kernel/hostname").map(|s| s.trim().to_owned()).unwrap_or_default();
    // A host name that is not a valid port name part (bassport::paths::check_name) is not used.
    if !h.is_empty() && h.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'.' || b == b'_') {
        h
    } else {
        "remote".into()
    }
}

#[cfg(test)]
mod tests;
