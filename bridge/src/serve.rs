//! `bass-bridge serve`: reads a local port like any reader and publishes every chunk on Zenoh.
//!
//! Each port (each acquisition) is sent from its **oldest frame still in the window**, not
//! from its live edge: after an upstream Acquire (serve reopens the new port within ~100 ms)
//! or when serve starts on a running port, the frames the port already holds reach the
//! replica too, so a reader of the replica from frame 1 gets what it gets locally (issue 20
//! item 5; the mirror starts its replica at the first frame it receives).
//!
//! A port is not read before a subscriber (a mirror) matches the chunk key, unless serve also
//! exports to iceoryx2: a serve started before any mirror connected does not put its backlog
//! to nobody; the first mirror gets the port from its oldest frame then still in the window.
//! That backlog goes through the bounded queue with blocking sends (bounded in time, see
//! [`CATCH_UP_PATIENCE`]) until the reader has caught up with the port. From then on the
//! port reader never waits for the network: chunks go through the bounded queue to a sender
//! thread that calls `put()`; when the queue is full the chunk is dropped, counted, and the
//! next sent chunk carries [`wire::flags::SOURCE_LOSS`] (its sequence number jumps). A port
//! that laps serve is counted exactly as such, in the backlog too.
//!
//! One name, one source: serve's liveliness token is `NS/<broker>/alive/<instance>`, and
//! another live instance of the same name is reported ([`conflict`]).

mod conflict;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use bassclient::{Error as PortError, Port, State};
use zenoh::sample::SampleKind;
use zenoh::Wait;

use crate::net::{self, NetOpts, SourceState};
use crate::wire;
use conflict::Conflicts;

/// Longest wait for room in the queue while the backlog goes out. A network that takes longer
/// (a dead link) ends the catch-up: from then on chunks are dropped and counted as usual, and
/// the port lapping serve meanwhile is counted as loss.
pub const CATCH_UP_PATIENCE: Duration = Duration::from_secs(1);

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
    /// Let mirrors forward control requests (ListDevices, Acquire, Stop, Status) to the local
    /// broker (docs/network.md, "Remote control"). Off: the path is read-only.
    #[arg(long)]
    pub allow_control: bool,
    /// Also offer each chunk on the iceoryx2 service `bass/<name>/chunks` (feature `iceoryx2`, on by default).
    #[arg(long)]
    pub iceoryx2: bool,
    #[command(flatten)]
    pub net: NetOpts,
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
    let term = net::termination_flag()?;
    let session = o.net.open()?;
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
    let publisher = session
        .declare_publisher(o.net.key(&o.name, "chunks"))
        .congestion_control(crate::net::CHUNK_CONGESTION)
        .wait()
        .map_err(|e| anyhow!("declare publisher: {e}"))?;
    // Whether any subscriber (a mirror) takes the chunks: a new port's backlog waits for one.
    let matched = Arc::new(AtomicBool::new(false));
    let m = matched.clone();
    publisher
        .matching_listener()
        .callback(move |s| m.store(s.matching(), Ordering::Relaxed))
        .background()
        .wait()
        .map_err(|e| anyhow!("matching listener: {e}"))?;
    let state_pub = session
        .declare_publisher(o.net.key(&o.name, "state"))
        .wait()
        .map_err(|e| anyhow!("declare state publisher: {e}"))?;
    let shared = Arc::new(Mutex::new(SourceState { ..Default::default() }));
    let info_shared = shared.clone();
    let info = session
        .declare_queryable(o.net.key(&o.name, "info"))
        .callback(move |q| {
            let s = serde_json::to_vec(&*info_shared.lock().unwrap_or_else(|e| e.into_inner()))
                .unwrap_or_default();
            if let Err(e) = q.reply(q.key_expr().clone(), s).wait() {
                tracing::debug!("info reply: {e}");
            }
        })
        .wait()
        .map_err(|e| anyhow!("declare info queryable: {e}"))?;
    let clock = session
        .declare_queryable(o.net.key(&o.name, "clock"))
        .callback(|q| {
            let now = bassclient::sys::monotonic_ns().to_le_bytes();
            if let Err(e) = q.reply(q.key_expr().clone(), now.to_vec()).wait() {
                tracing::debug!("clock reply: {e}");
            }
        })
        .wait()
        .map_err(|e| anyhow!("declare clock queryable: {e}"))?;

    let control = if o.allow_control {
        let key = o.net.key(&o.name, "control");
        Some(crate::control::declare_queryable(&session, &key, &o.name, faults.control_delay())?)
    } else {
        None
    };
    #[cfg(feature = "iceoryx2")]
    let mut iox = if o.iceoryx2 { Some(crate::iox::Exporter::new(&o.name)?) } else { None };
    #[cfg(not(feature = "iceoryx2"))]
    if o.iceoryx2 {
        anyhow::bail!("this bass-bridge was built without the iceoryx2 feature");
    }
    let (tx, rx) = sync_channel::<Outgoing>(o.queue as usize);
    let sender = std::thread::Builder::new().name("bridge-send".into()).spawn(move || {
        let mut faults = faults;
        for out in rx {
            for bytes in faults.apply(out.sequence, out.bytes) {
                if let Err(e) = publisher.put(bytes).wait() {
                    tracing::warn!("put: {e}");
                }
            }
        }
    })?;

    let (state_tx, state_rx) = sync_channel::<Vec<u8>>(1);
    let state_sender = std::thread::Builder::new().name("bridge-state".into()).spawn(move || {
        for b in state_rx {
            if let Err(e) = state_pub.put(b).wait() {
                tracing::debug!("state put: {e}");
            }
        }
    })?;

    tracing::info!(instance = %instance_hex, zid = %zid, name = %o.name, "serving");
    let mut sequence = 0u64;
    let mut reader = Reader {
        name: &o.name,
        tx: &tx,
        term: &term,
        matched: &matched,
        instance,
        sequence: &mut sequence,
        lost_frames: 0,
        pending_loss: false,
        batch: Batch { max: u64::from(o.chunks_per_message), ..Default::default() },
        sent: 0,
        dropped: 0,
        started: false,
        catching_up: false,
    };
    let mut last_state_pub = Instant::now() - Duration::from_secs(10);
    let mut publish_state = |s: &SourceState, force: bool| {
        let conflict = {
            let mut c = lock(&conflicts);
            for line in c.reminders(Instant::now()) {
                tracing::error!("{line}");
            }
            c.describe()
        };
        let mut cur = shared.lock().unwrap_or_else(|e| e.into_inner());
        let changed = (cur.state.as_str(), cur.epoch, cur.error_code, &cur.conflict)
            != (s.state.as_str(), s.epoch, s.error_code, &conflict);
        *cur = SourceState {
            instance: instance_hex.clone(),
            zid: zid.clone(),
            conflict,
            insecure: o.net.insecure,
            ..s.clone()
        };
        if changed || force || last_state_pub.elapsed() >= Duration::from_millis(500) {
            last_state_pub = Instant::now();
            // Through the state thread: a put may block (the chunks' put holds the link's
            // queue while it waits on a dead link), the port reader must not. A state that
            // finds the slot full is sent by the next refresh (within 500 ms).
            if let Ok(b) = serde_json::to_vec(&*cur) {
                let _ = state_tx.try_send(b);
            }
        }
    };
    while !term.load(Ordering::Relaxed) {
        let port = match Port::open(&o.name) {
            Ok(p) => p,
            Err(_) => {
                publish_state(
                    &SourceState { state: "gone".into(), message: "no port".into(), ..Default::default() },
                    false,
                );
                std::thread::sleep(Duration::from_millis(100));
                continue;
            }
        };
        reader.follow(
            &port,
            &term,
            &mut publish_state,
            #[cfg(feature = "iceoryx2")]
            iox.as_mut(),
        )?;
    }
    drop(reader);
    #[cfg(feature = "iceoryx2")]
    drop(iox);
    // Bounded exit (SIGTERM ends serve within a second in every state): the sender may be
    // blocked in a put on a dead link; it is given SENDER_PATIENCE, then left to the exit.
    drop(tx);
    drop(state_tx);
    if !wait_until_finished(&sender, SENDER_PATIENCE)
        || !wait_until_finished(&state_sender, Duration::from_millis(50))
    {
        // Closing the session would wait on the same dead link: the exit ends it all.
        tracing::warn!(
            "serve: a Zenoh put is still blocked after {} ms (a dead link?): terminated without \
             closing the session",
            SENDER_PATIENCE.as_millis()
        );
        return Ok(());
    }
    // Undeclaring and closing the session may wait on a link that just died: on a thread of
    // its own, given CLOSE_PATIENCE.
    let parts = (token, alive_sub, state_sub, info, clock, control, session);
    let closer = std::thread::Builder::new().name("bridge-close".into()).spawn(move || drop(parts))?;
    if !wait_until_finished(&closer, CLOSE_PATIENCE) {
        tracing::warn!(
            "serve: closing the Zenoh session takes longer than {} ms: not waited for",
            CLOSE_PATIENCE.as_millis()
        );
    }
    tracing::info!("serve: terminated");
    Ok(())
}

/// Waits up to `patience` for `thread` to finish; whether it did.
fn wait_until_finished<T>(thread: &std::thread::JoinHandle<T>, patience: Duration) -> bool {
    let t0 = Instant::now();
    while !thread.is_finished() {
        if t0.elapsed() >= patience {
            return false;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    true
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

struct Reader<'a> {
    name: &'a str,
    tx: &'a SyncSender<Outgoing>,
    term: &'a AtomicBool,
    /// Whether a subscriber takes the chunks (see `follow`).
    matched: &'a AtomicBool,
    instance: u64,
    sequence: &'a mut u64,
    lost_frames: u64,
    pending_loss: bool,
    batch: Batch,
    /// Chunks of the current port sent / dropped (queue full).
    sent: u64,
    dropped: u64,
    /// Whether a chunk of the current port was handed on (sent or dropped): frames that left
    /// the window before that are not the replica's (it starts at the first chunk it gets).
    started: bool,
    /// Sending the port's backlog: blocking sends until the reader has caught up.
    catching_up: bool,
}

/// Chunk messages waiting to go out together (`--chunks-per-message`).
#[derive(Default)]
struct Batch {
    max: u64,
    bytes: Vec<u8>,
    chunks: u64,
    first_sequence: u64,
    frames: u64,
}

impl Reader<'_> {
    /// Adds one encoded chunk message of `frames` frames; sends when the batch is full.
    fn push(&mut self, sequence: u64, bytes: Vec<u8>, frames: u64) -> Result<()> {
        self.started = true;
        if self.batch.chunks == 0 {
            self.batch.first_sequence = sequence;
            self.batch.bytes = bytes;
        } else {
            self.batch.bytes.extend_from_slice(&bytes);
        }
        self.batch.chunks += 1;
        self.batch.frames += frames;
        if self.batch.chunks >= self.batch.max {
            self.flush()?;
        }
        Ok(())
    }

    /// Hands the waiting chunks to the sender thread; a full queue drops them, counted —
    /// except while catching up, when it waits for room (up to [`CATCH_UP_PATIENCE`], and
    /// never past termination).
    fn flush(&mut self) -> Result<()> {
        if self.batch.chunks == 0 {
            return Ok(());
        }
        let (chunks, frames) = (self.batch.chunks, self.batch.frames);
        let mut out =
            Outgoing { sequence: self.batch.first_sequence, bytes: std::mem::take(&mut self.batch.bytes) };
        (self.batch.chunks, self.batch.frames) = (0, 0);
        let since = Instant::now();
        loop {
            match self.tx.try_send(out) {
                Ok(()) => {
                    self.sent += chunks;
                    self.pending_loss = false;
                    return Ok(());
                }
                Err(TrySendError::Full(back))
                    if self.catching_up
                        && since.elapsed() < CATCH_UP_PATIENCE
                        && !self.term.load(Ordering::Relaxed) =>
                {
                    out = back;
                    std::thread::sleep(Duration::from_micros(200));
                }
                Err(TrySendError::Full(_)) => {
                    if self.catching_up && !self.term.load(Ordering::Relaxed) {
                        tracing::warn!(
                            "the network took no chunk for {} ms while sending the port's backlog: \
                             dropping (counted) from here on",
                            CATCH_UP_PATIENCE.as_millis()
                        );
                        self.catching_up = false;
                    }
                    self.dropped += chunks;
                    self.lost_frames += frames;
                    self.pending_loss = true;
                    return Ok(());
                }
                Err(TrySendError::Disconnected(_)) => return Err(anyhow!("the sender thread ended")),
            }
        }
    }
}

fn state_name(s: Option<State>) -> &'static str {
    match s {
        Some(State::Idle) => "idle",
        Some(State::Starting) => "starting",
        Some(State::Capturing) => "capturing",
        Some(State::Stopped) => "stopped",
        Some(State::Error) => "error",
        Some(State::Superseded) | None => "gone",
    }
}

impl Reader<'_> {
    /// Follows one port until it is replaced, its writer dies, or termination.
    fn follow(
        &mut self,
        port: &Port,
        term: &AtomicBool,
        publish_state: &mut dyn FnMut(&SourceState, bool),
        #[cfg(feature = "iceoryx2")] mut iox: Option<&mut crate::iox::Exporter>,
    ) -> Result<()> {
        let info = port.info()?;
        let g = info.geometry.clone();
        let nfpc = u64::from(g.frames_per_chunk);
        let ch = g.channels as usize;
        // From the oldest frame still in the window (chunk-aligned), as a new epoch: what the
        // port already holds is sent as a backlog (see the module's comment).
        let oldest = (info.last_frame_index + 1).saturating_sub(info.frames_on_port).max(1);
        let mut nfr = (oldest - 1).div_ceil(nfpc) * nfpc + 1;
        let mut planes = vec![vec![0i32; nfpc as usize]; ch];
        let mut inter = vec![0i32; nfpc as usize * ch];
        (self.sent, self.dropped, self.started, self.catching_up) = (0, 0, false, true);
        if nfr <= info.last_frame_index {
            tracing::info!(
                epoch = info.epoch,
                first = nfr,
                last = info.last_frame_index,
                "sending the port from its oldest frame (a backlog of {} frames)",
                info.last_frame_index + 1 - nfr
            );
        }
        let state_of = |port: &Port, state: &str, sent, dropped| -> SourceState {
            let i = port.info().ok();
            SourceState {
                state: state.into(),
                error_code: i.as_ref().map_or(0, |i| i.error_code),
                message: i.as_ref().map_or(String::new(), |i| i.message.clone()),
                epoch: info.epoch,
                channels: g.channels,
                sample_rate: g.sample_rate,
                frames_per_chunk: g.frames_per_chunk,
                chunks_on_port: g.chunks_on_port,
                last_frame_index: i.as_ref().map_or(0, |i| i.last_frame_index),
                chunks_sent: sent,
                chunks_dropped: dropped,
                // Instance, Zenoh id and conflict: filled in by `publish_state`.
                ..Default::default()
            }
        };
        publish_state(&state_of(port, state_name(info.state), self.sent, self.dropped), true);
        let mut last_refresh = Instant::now();
        while !term.load(Ordering::Relaxed) {
            match port.wait(nfr + nfpc - 1, Duration::from_millis(200)) {
                Ok(_) => {}
                Err(PortError::Timeout { .. }) => {
                    // No chunk for a while: what waits in a batch goes now.
                    self.flush()?;
                    let st = current_state(port)?;
                    publish_state(&state_of(port, st, self.sent, self.dropped), false);
                    continue;
                }
                Err(PortError::Restarted) => return self.flush(),
                Err(PortError::Stopped { .. })
                | Err(PortError::Device { .. })
                | Err(PortError::WriterGone { .. }) => {
                    self.flush()?;
                    let st = current_state(port)?;
                    publish_state(&state_of(port, st, self.sent, self.dropped), false);
                    std::thread::sleep(Duration::from_millis(100));
                    // A new acquisition replaces the file: reopen when the epoch changed.
                    match Port::open(self.name) {
                        Ok(p) if p.info().map(|i| i.epoch != info.epoch).unwrap_or(false) => return Ok(()),
                        _ => continue,
                    }
                }
                Err(PortError::Interrupted) => continue,
                Err(e) => return Err(e.into()),
            }
            #[cfg(feature = "iceoryx2")]
            let exporting = iox.is_some();
            #[cfg(not(feature = "iceoryx2"))]
            let exporting = false;
            if !self.started && !exporting && !self.matched.load(Ordering::Relaxed) {
                // Nobody takes the chunks yet (serve just started, no mirror connected yet):
                // the port is not read, so the first mirror gets it from its oldest frame
                // still in the window rather than a backlog put to nobody.
                std::thread::sleep(Duration::from_millis(20));
                if last_refresh.elapsed() >= STATE_REFRESH {
                    let st = current_state(port)?;
                    publish_state(&state_of(port, st, self.sent, self.dropped), false);
                    last_refresh = Instant::now();
                }
                continue;
            }
            loop {
                let mut outs: Vec<&mut [i32]> = planes.iter_mut().map(|p| p.as_mut_slice()).collect();
                let before = nfr;
                let r = port.get_audio_data(nfpc as usize, &mut nfr, &mut outs)?;
                if r.frames == 0 {
                    // Caught up with the port (the backlog, if any, is out): from here on
                    // the reader never waits for the network.
                    self.catching_up = false;
                    break;
                }
                // Frames that left the window before the first chunk of this port went out
                // are not lost to the replica: it starts at the first chunk it receives.
                if r.loss > 0 && self.started {
                    // The port lapped us (we were descheduled): say so in the next message.
                    self.lost_frames += r.loss;
                    self.pending_loss = true;
                    *self.sequence += r.loss.div_ceil(nfpc);
                }
                let first = nfr - r.frames as u64;
                if r.frames as u64 != nfpc || (first - 1) % nfpc != 0 {
                    // A torn chunk (overwritten while copied): count it and realign.
                    let next = (nfr - 1).div_ceil(nfpc) * nfpc + 1;
                    if self.started {
                        self.lost_frames += next - before - r.loss;
                        self.pending_loss = true;
                    }
                    nfr = next;
                    continue;
                }
                let ci = port.chunk_info(first).ok();
                let src_flags = ci.map_or(0, |c| c.flags);
                let gap = src_flags & bassclient::format::chunk_flags::GAP != 0;
                let mut flags = 0;
                if gap {
                    flags |= wire::flags::GAP;
                }
                if src_flags & bassclient::format::chunk_flags::DISCONTINUITY != 0 {
                    flags |= wire::flags::DISCONTINUITY;
                }
                if src_flags & bassclient::format::chunk_flags::TIME_ESTIMATED != 0 {
                    flags |= wire::flags::TIME_ESTIMATED;
                }
                if self.pending_loss {
                    flags |= wire::flags::SOURCE_LOSS;
                }
                for (f, frame) in inter.chunks_exact_mut(ch).enumerate() {
                    for (c, s) in frame.iter_mut().enumerate() {
                        *s = planes[c][f];
                    }
                }
                let h = wire::Header {
                    flags,
                    instance: self.instance,
                    epoch: info.epoch,
                    sequence: *self.sequence,
                    first_frame: first,
                    frames: nfpc as u32,
                    channels: g.channels as u16,
                    sample_rate: g.sample_rate,
                    chunks_on_port: g.chunks_on_port,
                    mono_ns: ci.map_or(0, |c| c.mono_ns),
                    realtime_ns: ci.map_or(0, |c| c.realtime_ns),
                    send_mono_ns: bassclient::sys::monotonic_ns(),
                    source_lost: self.lost_frames,
                    ..Default::default()
                };
                #[cfg(feature = "iceoryx2")]
                if let Some(x) = iox.as_deref_mut() {
                    x.publish(&h, &inter);
                }
                let bytes = wire::encode(&h, if gap { &[] } else { &inter });
                self.push(*self.sequence, bytes, nfpc)?;
                *self.sequence += 1;
            }
            // The state others see (queryable, liveliness, status) is refreshed at most every
            // STATE_REFRESH while data flows: reading the port's info checks the writer's
            // liveness, and at 750 chunks/s that was most of serve's CPU time.
            if last_refresh.elapsed() >= STATE_REFRESH {
                let st = current_state(port)?;
                publish_state(&state_of(port, st, self.sent, self.dropped), false);
                last_refresh = Instant::now();
            }
        }
        self.flush()
    }
}

/// The port's state name, `gone` when its writer process died.
fn current_state(port: &Port) -> Result<&'static str> {
    let i = port.info()?;
    Ok(if i.writer_alive { state_name(i.state) } else { "gone" })
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::mpsc::sync_channel;
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    use bass_test_support::TempDir;
    use bassclient::testsignal::{fill_pattern_interleaved, pattern_expected};
    use bassclient::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
    use clap::{CommandFactory, Parser};

    use super::{Batch, Outgoing, Reader};
    use crate::wire;

    /// What `Reader::follow` sends of a port (nFPC 4, nCOP 16: nFOP 64, 2 channels) that has
    /// published `chunks` chunks, through a queue of one message to a slow network (the
    /// receiver takes a message every 2 ms), until `want` chunks arrived or 5 s passed.
    /// Returns the chunks received and the reader's (dropped chunks, lost frames).
    fn follow_a_port(tag: &str, chunks: u64, want: usize) -> (Vec<wire::Chunk>, u64, u64) {
        let dir = TempDir::shm(tag);
        let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 4, chunks_on_port: 16 };
        let path = dir.join("bass-src.port");
        let mut w =
            Writer::create_at(&path, &PortParams { geometry, device: "test".into(), group: None }).unwrap();
        let mut s = vec![0; 8];
        for _ in 0..chunks {
            fill_pattern_interleaved(&mut s, 2, w.last_frame_index() + 1);
            w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
        }
        let port = Port::open_path(&path).unwrap();
        let term = Arc::new(AtomicBool::new(false));
        let (tx, rx) = sync_channel::<Outgoing>(1);
        let stop = term.clone();
        let network = std::thread::spawn(move || {
            let (mut got, t0) = (Vec::new(), Instant::now());
            while got.len() < want && t0.elapsed() < Duration::from_secs(5) {
                if let Ok(out) = rx.recv_timeout(Duration::from_millis(50)) {
                    got.extend(wire::decode_batch(&out.bytes).unwrap());
                    std::thread::sleep(Duration::from_millis(2));
                }
            }
            stop.store(true, Ordering::Relaxed);
            got
        });
        let mut sequence = 0;
        let mut reader = Reader {
            name: "src",
            tx: &tx,
            term: &term,
            matched: &AtomicBool::new(true),
            instance: 7,
            sequence: &mut sequence,
            lost_frames: 0,
            pending_loss: false,
            batch: Batch { max: 1, ..Default::default() },
            sent: 0,
            dropped: 0,
            started: false,
            catching_up: false,
        };
        reader
            .follow(
                &port,
                &term,
                &mut |_, _| {},
                #[cfg(feature = "iceoryx2")]
                None,
            )
            .unwrap();
        let (dropped, lost) = (reader.dropped, reader.lost_frames);
        drop(reader);
        drop(tx);
        let got = network.join().unwrap();
        w.remove().unwrap();
        (got, dropped, lost)
    }

    fn check_chunks(got: &[wire::Chunk], first: u64) {
        for (k, c) in got.iter().enumerate() {
            let f = first + 4 * k as u64;
            assert_eq!(c.header.first_frame, f, "chunk {k}");
            assert_eq!(c.header.flags & wire::flags::SOURCE_LOSS, 0, "chunk {k} flagged as after a loss");
            for (i, frame) in c.samples.chunks_exact(2).enumerate() {
                let g = f + i as u64;
                assert_eq!(frame, [pattern_expected(g, 0), pattern_expected(g, 1)], "frame {g}");
            }
        }
    }

    /// Issue 20 item 5, serve's side: a port that serve (re)opens — after an upstream Acquire,
    /// or a serve started on a running port — is sent from its oldest frame still in the
    /// window, and that backlog goes through a full queue without a drop.
    #[test]
    fn a_new_port_is_sent_from_its_oldest_frame_and_its_backlog_is_never_dropped() {
        // 10 chunks published, the window not yet full: frames 1..=40 are all sent.
        let (got, dropped, lost) = follow_a_port("serve-backlog", 10, 10);
        assert_eq!(got.len(), 10, "the backlog of 10 chunks");
        check_chunks(&got, 1);
        assert_eq!((dropped, lost), (0, 0));
        // 30 chunks published: the window holds frames 57..=120, its 16 chunks are sent.
        let (got, dropped, lost) = follow_a_port("serve-midstream", 30, 16);
        assert_eq!(got.len(), 16, "the window's 16 chunks");
        check_chunks(&got, 57);
        assert_eq!((dropped, lost), (0, 0));
    }

    #[derive(Parser)]
    struct Cli {
        #[command(subcommand)]
        cmd: crate::Cmd,
    }

    /// serve's numeric options; every other option taking a value is text (a name, a path,
    /// an endpoint, a choice). A new option must be put in one list or the other.
    const NUMERIC: &[(&str, u64, u64)] = &[("queue", 1, 16), ("chunks-per-message", 1, 64)];
    const TEXT: &[&str] = &["name", "zenoh-config", "mode", "listen", "connect", "namespace", "credentials"];

    fn parse(args: &[&str]) -> Result<Cli, clap::Error> {
        Cli::try_parse_from(["bass-bridge", "serve"].iter().chain(args))
    }

    /// Issue 20 item 7: inf, NaN, 1e300 and every other number out of range or not whole is
    /// a usage error (exit status 2) naming the option, as in `bass`; nothing panics.
    #[test]
    fn every_numeric_option_refuses_inf_nan_and_out_of_range_values_naming_itself() {
        let cmd = Cli::command();
        let serve = cmd.find_subcommand("serve").expect("serve");
        for arg in serve.get_arguments().filter(|a| a.get_action().takes_values()) {
            let long = arg.get_long().expect("long options only");
            assert!(
                NUMERIC.iter().any(|(n, _, _)| *n == long) || TEXT.contains(&long),
                "--{long}: classify it as NUMERIC (and test it) or TEXT"
            );
        }
        for &(opt, lo, hi) in NUMERIC {
            let flag = format!("--{opt}");
            let (below, above) = ((lo - 1).to_string(), (hi + 1).to_string());
            for v in [
                "inf",
                "-inf",
                "NaN",
                "1e300",
                "-1",
                "1.5",
                "",
                "0x10",
                "18446744073709551616",
                &below,
                &above,
            ] {
                // `--opt=VALUE`: a value starting with '-' is a value, not another option.
                let e = match parse(&[&format!("{flag}={v}")]) {
                    Ok(_) => panic!("{flag} {v:?} accepted"),
                    Err(e) => e,
                };
                assert_eq!(e.exit_code(), 2, "{flag} {v:?}: {e}");
                assert!(e.to_string().contains(&flag), "{flag} {v:?}: the error names the option: {e}");
            }
            for v in [lo, hi] {
                assert!(parse(&[&flag, &v.to_string()]).is_ok(), "{flag} {v} is accepted");
            }
        }
    }
}
