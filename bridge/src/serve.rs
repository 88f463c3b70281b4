//! `bass-bridge serve`: reads a local port like any reader and publishes every chunk on Zenoh.
//!
//! The port reader never waits for the network: chunks go through a bounded queue to a
//! sender thread that calls `put()`; when the queue is full the chunk is dropped, counted,
//! and the next sent chunk carries [`wire::flags::SOURCE_LOSS`] (its sequence number jumps).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use bassclient::{Error as PortError, Port, State};
use zenoh::qos::CongestionControl;
use zenoh::Wait;

use crate::net::{self, NetOpts, SourceState};
use crate::wire;

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
    /// Also offer each chunk on the iceoryx2 service `bass/<name>/chunks` (feature `iceoryx2`).
    #[arg(long)]
    pub iceoryx2: bool,
    /// Deterministic faults by sequence number (tests): e.g. `drop=5,dup=7,reorder=9,delay=11`;
    /// `control-delay=MS` holds each forwarded control request.
    #[arg(long)]
    pub fault: Option<String>,
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
pub fn run(o: ServeOpts) -> Result<()> {
    let term = net::termination_flag()?;
    let session = o.net.open()?;
    let _token = session
        .liveliness()
        .declare_token(o.net.key(&o.name, "alive"))
        .wait()
        .map_err(|e| anyhow!("liveliness token: {e}"))?;
    let publisher = session
        .declare_publisher(o.net.key(&o.name, "chunks"))
        .congestion_control(CongestionControl::Block)
        .wait()
        .map_err(|e| anyhow!("declare publisher: {e}"))?;
    let state_pub = session
        .declare_publisher(o.net.key(&o.name, "state"))
        .wait()
        .map_err(|e| anyhow!("declare state publisher: {e}"))?;
    let shared = Arc::new(Mutex::new(SourceState { ..Default::default() }));
    let info_shared = shared.clone();
    let _info = session
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
    let _clock = session
        .declare_queryable(o.net.key(&o.name, "clock"))
        .callback(|q| {
            let now = bassclient::sys::monotonic_ns().to_le_bytes();
            if let Err(e) = q.reply(q.key_expr().clone(), now.to_vec()).wait() {
                tracing::debug!("clock reply: {e}");
            }
        })
        .wait()
        .map_err(|e| anyhow!("declare clock queryable: {e}"))?;

    let faults = crate::fault::Faults::parse(o.fault.as_deref())?;
    let _control = if o.allow_control {
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

    let instance = net::instance_id();
    tracing::info!(instance = format!("{instance:016x}"), name = %o.name, "serving");
    let mut sequence = 0u64;
    let mut reader = Reader {
        name: &o.name,
        tx: &tx,
        instance,
        sequence: &mut sequence,
        lost_frames: 0,
        pending_loss: false,
        batch: Batch { max: u64::from(o.chunks_per_message), ..Default::default() },
        sent: 0,
        dropped: 0,
    };
    let mut last_state_pub = Instant::now() - Duration::from_secs(10);
    let mut publish_state = |s: &SourceState, force: bool| {
        let mut cur = shared.lock().unwrap_or_else(|e| e.into_inner());
        let changed =
            (cur.state.as_str(), cur.epoch, cur.error_code) != (s.state.as_str(), s.epoch, s.error_code);
        *cur = SourceState { ..s.clone() };
        if changed || force || last_state_pub.elapsed() >= Duration::from_millis(500) {
            last_state_pub = Instant::now();
            if let Ok(b) = serde_json::to_vec(&*cur) {
                if let Err(e) = state_pub.put(b).wait() {
                    tracing::debug!("state put: {e}");
                }
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
    drop(tx);
    let _ = sender.join();
    tracing::info!("serve: terminated");
    Ok(())
}

struct Reader<'a> {
    name: &'a str,
    tx: &'a SyncSender<Outgoing>,
    instance: u64,
    sequence: &'a mut u64,
    lost_frames: u64,
    pending_loss: bool,
    batch: Batch,
    /// Chunks of the current port sent / dropped (queue full).
    sent: u64,
    dropped: u64,
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

    /// Hands the waiting chunks to the sender thread; a full queue drops them, counted.
    fn flush(&mut self) -> Result<()> {
        if self.batch.chunks == 0 {
            return Ok(());
        }
        let (chunks, frames) = (self.batch.chunks, self.batch.frames);
        let out =
            Outgoing { sequence: self.batch.first_sequence, bytes: std::mem::take(&mut self.batch.bytes) };
        (self.batch.chunks, self.batch.frames) = (0, 0);
        match self.tx.try_send(out) {
            Ok(()) => {
                self.sent += chunks;
                self.pending_loss = false;
            }
            Err(TrySendError::Full(_)) => {
                self.dropped += chunks;
                self.lost_frames += frames;
                self.pending_loss = true;
            }
            Err(TrySendError::Disconnected(_)) => return Err(anyhow!("the sender thread ended")),
        }
        Ok(())
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
        let mut nfr = info.last_frame_index + 1;
        let mut planes = vec![vec![0i32; nfpc as usize]; ch];
        let mut inter = vec![0i32; nfpc as usize * ch];
        (self.sent, self.dropped) = (0, 0);
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
            loop {
                let mut outs: Vec<&mut [i32]> = planes.iter_mut().map(|p| p.as_mut_slice()).collect();
                let before = nfr;
                let r = port.get_audio_data(nfpc as usize, &mut nfr, &mut outs)?;
                if r.frames == 0 {
                    break;
                }
                if r.loss > 0 {
                    // The port lapped us (we were descheduled): say so in the next message.
                    self.lost_frames += r.loss;
                    self.pending_loss = true;
                    *self.sequence += r.loss.div_ceil(nfpc);
                }
                let first = nfr - r.frames as u64;
                if r.frames as u64 != nfpc || (first - 1) % nfpc != 0 {
                    // A torn chunk (overwritten while copied): count it and realign.
                    let next = (nfr - 1).div_ceil(nfpc) * nfpc + 1;
                    self.lost_frames += next - before - r.loss;
                    self.pending_loss = true;
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
