//! `bass-bridge serve`: reads a local port like any reader and publishes every chunk on Zenoh.
//!
//! Each port (each acquisition) is sent from its **oldest frame still in the window**, not
//! from its live edge: after an upstream Acquire (serve reopens the new port within ~100 ms)
//! or when serve starts on a running port, the frames the port already holds reach the
//! replica too, so a reader of the replica from frame 1 gets what it gets locally (issue 20
//! item 5; the mirror starts its replica at the first frame it receives).
//!
//! A port is not read before a subscriber (a mirror) matches the chunk key, unless serve also
//! exports to iceoryx2 or to ROS 2 (`--ros2`, [`crate::ros2`]): a serve started before any mirror connected does not put its backlog
//! to nobody; the first mirror gets the port from its oldest frame then still in the window.
//! That backlog goes through the bounded queue with blocking sends (bounded in time, see
//! [`CATCH_UP_PATIENCE`]) until the reader has caught up with the port. From then on the
//! port reader never waits for the network: chunks go through the bounded queue to a sender
//! thread that calls `put()`; when the queue is full the chunk is dropped, counted, and the
//! next sent chunk carries [`crate::wire::flags::SOURCE_LOSS`] (its sequence number jumps). A port
//! that laps serve is counted exactly as such, in the backlog too.
//!
//! One name, one source: serve's liveliness token is `NS/<broker>/alive/<instance>`, and
//! another live instance of the same name is reported ([`conflict`]).

mod conflict;
mod reader;
mod state;
#[cfg(test)]
mod tests;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use bassport::Port;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::query::Queryable;
use zenoh::sample::SampleKind;
use zenoh::Wait;

use crate::net::{self, BridgeState, NetOpts, SourceState};
use conflict::Conflicts;
use reader::Reader;
use state::StatePublisher;

use crate::patience::wait_until_finished;
pub use crate::patience::CATCH_UP_PATIENCE;

/// Longest wait at exit for the sender thread (it may be blocked in a `put()` on a dead link).
pub const SENDER_PATIENCE: Duration = Duration::from_millis(250);

/// Longest wait at exit for Zenoh's own teardown (closing the session may wait on a dead link).
const CLOSE_PATIENCE: Duration = Duration::from_millis(250);

/// How often the published source state is refreshed while chunks flow.
const STATE_REFRESH: Duration = Duration::from_millis(200);

/// Options of `serve`.
#[derive(clap::Args, Debug)]
pub struct ServeOpts {
    /// Local broker (port) name to export.
    #[arg(long, default_value = "default")]
    pub name: String,
    /// Chunks queued in front of the network before the bridge drops (1..=16).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub queue: u32,
    /// Chunks sent in one Zenoh message (1..=64). More costs less CPU and fewer bytes per
    /// chunk on small chunks, and delays a chunk by up to N-1 chunk periods
    /// (docs/network.md, "Small chunks"). Mirrors of this version or later read any N.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub chunks_per_message: u32,
    /// Let the named identities (of --credentials, comma-separated: `--allow-control ws1,ws2`)
    /// forward control requests (ListDevices, Acquire, Stop, Status) to the local broker
    /// (docs/network.md, "Remote control"). Without it the path is read-only.
    #[arg(long, value_name = "NAMES", num_args = 0..=1, default_missing_value = "", value_delimiter = ',')]
    pub allow_control: Option<Vec<String>>,
    /// Also offer each chunk on the iceoryx2 service `bass/<name>/chunks` (feature `iceoryx2`, on by default).
    #[arg(long)]
    pub iceoryx2: bool,
    #[command(flatten)]
    pub net: NetOpts,
    #[command(flatten)]
    pub ros2: crate::ros2::Ros2Opts,
}

/// One message for the sender thread.
pub struct Outgoing {
    /// Sequence number.
    pub sequence: u64,
    /// Encoded message.
    pub bytes: Vec<u8>,
}

/// Runs `serve` until SIGTERM/SIGINT.
pub fn run(o: ServeOpts, faults: crate::fault::Faults) -> Result<()> {
    check(&o)?;
    let term = net::termination_flag()?;
    let guarded = if o.ros2.ros2 { crate::ros2::guarded_keys(&o.ros2, &o.name)? } else { Vec::new() };
    let opened = o.net.open(net::Role::Serve(guarded))?;
    let (session, cred) = (opened.session, opened.credentials.map(Arc::new));
    if let (Some(names), Some(cred)) = (&o.allow_control, &cred) {
        crate::control::check_trusted(names, cred)?;
    }
    let instance = net::instance_id();
    let instance_hex = format!("{instance:016x}");
    let zid = session.zid().to_string();
    let alive_key = o.net.key(&o.name, "alive");
    let token = session
        .liveliness()
        .declare_token(format!("{alive_key}/{instance_hex}"))
        .wait()
        .map_err(|e| anyhow!("liveliness token: {e}"))?;
    // Other serve instances of this name: their tokens, and their states for their Zenoh ids.
    let conflicts = Arc::new(Mutex::new(Conflicts::new(&instance_hex, &zid)));
    let (alive_sub, state_sub) = watch_conflicts(&session, &o, alive_key, &conflicts)?;
    let (publisher, matched) = chunk_publisher(&session, &o)?;
    let state_pub = session
        .declare_publisher(o.net.key(&o.name, "state"))
        .wait()
        .map_err(|e| anyhow!("declare state publisher: {e}"))?;
    let shared = Arc::new(Mutex::new(SourceState { ..Default::default() }));
    let info = declare_info(&session, &o, shared.clone(), cred.clone())?;
    let clock_faults = faults.clock();
    let clock = declare_clock(&session, &o, cred.as_deref(), clock_faults)?;
    let control_stats = Arc::new(crate::control::Audit::default());
    let control = declare_control(&session, &o, cred.as_ref(), faults.control_delay(), &control_stats)?;
    #[cfg(feature = "iceoryx2")]
    let mut iox = if o.iceoryx2 { Some(crate::iox::Exporter::new(&o.name)?) } else { None };
    #[cfg(not(feature = "iceoryx2"))]
    let mut iox: Option<reader::NoExport> = if o.iceoryx2 {
        anyhow::bail!("this bass-bridge was built without the iceoryx2 feature");
    } else {
        None
    };
    let (ros2_graph, ros2) = match o.ros2.ros2 {
        true => {
            let (g, e) =
                crate::ros2::start(&session, &o.ros2, &o.name, crate::ros2::QUEUE.max(o.queue as usize))?;
            (Some(g), Some(e))
        }
        false => (None, None),
    };
    let (tx, rx) = sync_channel::<Outgoing>(o.queue as usize);
    let sender = spawn_sender(publisher, rx, faults, o.net.key(&o.name, "chunks"), cred.as_deref())?;
    let (state_tx, state_rx) = sync_channel::<Vec<u8>>(1);
    let state_sender = spawn_state_sender(state_pub, state_rx, o.net.key(&o.name, "state"), cred.clone())?;

    tracing::info!(instance = %instance_hex, zid = %zid, name = %o.name, "serving");
    let mut reader = Reader::new(&o.name, &tx, &term, &matched, instance, o.chunks_per_message);
    reader.ros2 = ros2;
    reader.clock = clock_faults.source;
    let mut states = StatePublisher {
        shared,
        conflicts,
        tx: state_tx,
        instance: instance_hex,
        zid,
        insecure: o.net.insecure,
        last: None,
        control: control_stats,
    };
    let publish_state = &mut |s: &SourceState, force: bool| states.publish(s, force);
    while !term.load(Ordering::Relaxed) {
        let Ok(port) = Port::open(&o.name) else {
            let gone =
                SourceState { state: BridgeState::Gone, message: "no port".into(), ..Default::default() };
            publish_state(&gone, false);
            std::thread::sleep(Duration::from_millis(100));
            continue;
        };
        reader.follow(&port, publish_state, iox.as_mut())?;
    }
    let ros2_done = reader.ros2.take().map_or(true, |r| r.finish(SENDER_PATIENCE));
    drop(reader);
    drop(iox);
    // Bounded exit (SIGTERM ends serve within a second in every state): the sender may be
    // blocked in a put on a dead link; it is given SENDER_PATIENCE, then left to the exit.
    drop(tx);
    drop(states);
    if !senders_finished(&sender, &state_sender, ros2_done) {
        // Closing the session would wait on the same dead link: the exit ends it all.
        return Ok(());
    }
    // Undeclaring and closing the session may wait on a link that just died.
    close((token, alive_sub, state_sub, info, clock, control, ros2_graph, session))?;
    tracing::info!("serve: terminated");
    Ok(())
}

/// The options checked before anything is opened.
fn check(o: &ServeOpts) -> Result<()> {
    if o.ros2.ros2 {
        crate::ros2::check(&o.ros2, &o.name)?;
    }
    net::check_key_name("--name", &o.name)?;
    net::check_namespace(&o.net.namespace)?;
    if let Some(names) = &o.allow_control {
        crate::control::check_allowed(names, o.net.credentials.is_some())?;
    }
    Ok(())
}

/// The subscribers that report other serve instances of this name ([`Conflicts`]): their
/// liveliness tokens under `alive_key`, and their states (for their Zenoh ids).
fn watch_conflicts(
    session: &zenoh::Session,
    o: &ServeOpts,
    alive_key: String,
    conflicts: &Arc<Mutex<Conflicts>>,
) -> Result<(Subscriber<()>, Subscriber<()>)> {
    let (c_alive, c_state) = (conflicts.clone(), conflicts.clone());
    let alive_sub = session
        .liveliness()
        .declare_subscriber(format!("{alive_key}/**"))
        .history(true)
        .callback(move |s| {
            if let Some(other) = conflict::instance_of_key(s.key_expr().as_str(), &alive_key) {
                let line = lock(&c_alive).on_token(other, s.kind() == SampleKind::Put, Instant::now());
                if let Some(line) = line {
                    tracing::error!("{line}");
                }
            }
        })
        .wait()
        .map_err(|e| anyhow!("liveliness subscriber: {e}"))?;
    let state_sub = session
        .declare_subscriber(o.net.key(&o.name, "state"))
        .callback(move |s| {
            if let Ok(st) = serde_json::from_slice::<SourceState>(&s.payload().to_bytes()) {
                if let Some(line) = lock(&c_state).on_state(&st.instance, &st.zid, Instant::now()) {
                    tracing::error!("{line}");
                }
            }
        })
        .wait()
        .map_err(|e| anyhow!("state subscriber: {e}"))?;
    Ok((alive_sub, state_sub))
}

/// The chunk publisher ([`net::CHUNK_CONGESTION`]), and whether any subscriber (a mirror)
/// takes the chunks: a new port's backlog waits for one.
fn chunk_publisher(session: &zenoh::Session, o: &ServeOpts) -> Result<(Publisher<'static>, Arc<AtomicBool>)> {
    let publisher = session
        .declare_publisher(o.net.key(&o.name, "chunks"))
        .congestion_control(crate::net::CHUNK_CONGESTION)
        .express(crate::net::CHUNK_EXPRESS)
        .priority(crate::net::CHUNK_PRIORITY)
        .wait()
        .map_err(|e| anyhow!("declare publisher: {e}"))?;
    let matched = Arc::new(AtomicBool::new(false));
    let m = matched.clone();
    publisher
        .matching_listener()
        .callback(move |s| m.store(s.matching(), Ordering::Relaxed))
        .background()
        .wait()
        .map_err(|e| anyhow!("matching listener: {e}"))?;
    Ok((publisher, matched))
}

/// The `info` queryable: the source state in `info_shared`, signed with `info_cred`.
fn declare_info(
    session: &zenoh::Session,
    o: &ServeOpts,
    info_shared: Arc<Mutex<SourceState>>,
    info_cred: Option<Arc<crate::credentials::Credentials>>,
) -> Result<Queryable<()>> {
    let info_key = o.net.key(&o.name, "info");
    session
        .declare_queryable(info_key.clone())
        .callback(move |q| {
            let s = serde_json::to_vec(&*info_shared.lock().unwrap_or_else(|e| e.into_inner()))
                .unwrap_or_default();
            let sig = info_cred.as_ref().map(|c| c.sign(&info_key, &s).to_vec());
            if let Err(e) = q.reply(q.key_expr().clone(), s).attachment(sig).wait() {
                tracing::debug!("info reply: {e}");
            }
        })
        .wait()
        .map_err(|e| anyhow!("declare info queryable: {e}"))
}

/// The `clock` queryable: this host's CLOCK_MONOTONIC, with `cred` a keyed answer; `faults`
/// (none but in the fault build's tests) hold the probes and answers and move the clock.
fn declare_clock(
    session: &zenoh::Session,
    o: &ServeOpts,
    cred: Option<&crate::credentials::Credentials>,
    faults: crate::fault::ClockFaults,
) -> Result<Queryable<()>> {
    let (clock_key, clock_keys) = (o.net.key(&o.name, "clock"), cred.map(crate::clock::ReplyKeys::new));
    let (delay, rng) = (faults.delay, std::sync::atomic::AtomicU64::new(0x9e37_79b9_7f4a_7c15));
    let pause = move |d: Duration| {
        if !d.is_zero() {
            std::thread::sleep(d);
        }
    };
    session
        .declare_queryable(clock_key.clone())
        .callback(move |q| {
            pause(crate::fault::jitter(&rng, faults.jitter));
            let now = faults.source.mono(bassport::sys::monotonic_ns()).to_le_bytes();
            // A keyed answer (HMAC, ~1 us, not a signature's ~20 us that would skew the probe).
            let sig = clock_keys.as_ref().and_then(|k| {
                k.answer(
                    &clock_key,
                    q.attachment().map(|a| a.to_bytes()).as_deref().unwrap_or_default(),
                    &now,
                )
            });
            pause(delay + crate::fault::jitter(&rng, faults.jitter));
            if let Err(e) = q.reply(q.key_expr().clone(), now.to_vec()).attachment(sig).wait() {
                tracing::debug!("clock reply: {e}");
            }
        })
        .wait()
        .map_err(|e| anyhow!("declare clock queryable: {e}"))
}

/// The `control` queryable, with `--allow-control` and credentials: the named identities'
/// signed control requests to the local broker ([`crate::control`]), counted in `stats`.
fn declare_control(
    session: &zenoh::Session,
    o: &ServeOpts,
    cred: Option<&Arc<crate::credentials::Credentials>>,
    delay: Duration,
    stats: &Arc<crate::control::Audit>,
) -> Result<Option<Queryable<()>>> {
    Ok(match (&o.allow_control, cred) {
        (Some(allowed), Some(cred)) => {
            let key = o.net.key(&o.name, "control");
            let policy = crate::control::Policy {
                allowed: allowed.clone(),
                credentials: cred.clone(),
                key: key.clone(),
            };
            Some(crate::control::declare_queryable(session, &key, &o.name, delay, policy, stats.clone())?)
        }
        _ => None,
    })
}

/// The sender thread: each message from the reader's bounded queue, through the test
/// `faults`, signed with `cred`, put on `chunk_key`.
fn spawn_sender(
    publisher: Publisher<'static>,
    rx: Receiver<Outgoing>,
    faults: crate::fault::Faults,
    chunk_key: String,
    cred: Option<&crate::credentials::Credentials>,
) -> Result<std::thread::JoinHandle<()>> {
    let mut chunk_signer = cred.map(|c| c.signer());
    Ok(std::thread::Builder::new().name("bridge-send".into()).spawn(move || {
        let mut faults = faults;
        for out in rx {
            for bytes in faults.apply(out.sequence, out.bytes) {
                let sig = chunk_signer.as_mut().map(|s| s.sign(&chunk_key, &bytes).to_vec());
                if let Err(e) = publisher.put(bytes).attachment(sig).wait() {
                    tracing::warn!("put: {e}");
                }
            }
        }
    })?)
}

/// The state thread: each state message, signed with `state_cred`, put on `state_key`.
fn spawn_state_sender(
    state_pub: Publisher<'static>,
    state_rx: Receiver<Vec<u8>>,
    state_key: String,
    state_cred: Option<Arc<crate::credentials::Credentials>>,
) -> Result<std::thread::JoinHandle<()>> {
    Ok(std::thread::Builder::new().name("bridge-state".into()).spawn(move || {
        for b in state_rx {
            let sig = state_cred.as_ref().map(|c| c.sign(&state_key, &b).to_vec());
            if let Err(e) = state_pub.put(b).attachment(sig).wait() {
                tracing::debug!("state put: {e}");
            }
        }
    })?)
}

/// Whether the sender threads finished within their patience (SENDER_PATIENCE) and the ROS 2
/// export did (`ros2_done`); if not, a put is still blocked (a dead link?), said in the log.
fn senders_finished(
    sender: &std::thread::JoinHandle<()>,
    state_sender: &std::thread::JoinHandle<()>,
    ros2_done: bool,
) -> bool {
    if !ros2_done
        || !wait_until_finished(sender, SENDER_PATIENCE)
        || !wait_until_finished(state_sender, Duration::from_millis(50))
    {
        tracing::warn!(
            "serve: a Zenoh put is still blocked after {} ms (a dead link?): terminated without \
             closing the session",
            SENDER_PATIENCE.as_millis()
        );
        return false;
    }
    true
}

/// Undeclares and closes `parts` (in their order) on a thread of its own, given CLOSE_PATIENCE:
/// it may wait on a link that just died.
fn close(parts: impl Send + 'static) -> Result<()> {
    let closer = std::thread::Builder::new().name("bridge-close".into()).spawn(move || drop(parts))?;
    if !wait_until_finished(&closer, CLOSE_PATIENCE) {
        tracing::warn!(
            "serve: closing the Zenoh session takes longer than {} ms: not waited for",
            CLOSE_PATIENCE.as_millis()
        );
    }
    Ok(())
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}
