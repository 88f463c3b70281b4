//! `bass-bridge mirror`: subscribes to one source and writes a local replica port at the
//! source's frame indices, so every local client reads remote audio unchanged.
//!
//! Rules (docs/network.md, "Guarantees"):
//! - a chunk at the expected frame is published as it is;
//! - a chunk ahead of it: the frames in between are published as zero-filled GAP frames and
//!   counted in the port's `lost_upstream_frames` (network or source-side loss);
//! - a chunk behind it (late, duplicate): dropped and counted;
//! - a new source epoch or geometry: a new replica port (readers see RESTARTED);
//! - a new `serve` instance with the same epoch: the port is kept and the gap filled;
//! - source unreachable (liveliness lost, or silent) longer than `--timeout`, or the source
//!   port in error or gone: the replica shows a device error; data brings it back.

use std::sync::atomic::Ordering;
use std::sync::mpsc::{channel, RecvTimeoutError};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use bassclient::format::{chunk_flags, error_code};
use bassclient::{ChunkMeta, Geometry, PortParams, Source, State, Writer};
use serde::Serialize;
use zenoh::sample::SampleKind;
use zenoh::Wait;

use crate::clock::ClockEstimator;
use crate::net::{self, NetOpts, SourceState};
use crate::wire;

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
    #[arg(long, default_value_t = 2.0)]
    pub timeout: f64,
    /// Write the mirror's counters and clock estimate as JSON to this file, once a second.
    #[arg(long)]
    pub status_file: Option<std::path::PathBuf>,
    /// Seconds between clock probes.
    #[arg(long, default_value_t = 0.5)]
    pub probe_interval: f64,
    #[command(flatten)]
    pub net: NetOpts,
}

/// What the subscribers other than the chunks' report to the main loop.
enum Event {
    State(Vec<u8>),
    Alive(bool),
}

/// The replica and its counters, shared by the chunk subscriber (which writes chunks on
/// Zenoh's receiving thread: no hand-over to another thread per chunk) and the main loop
/// (state, liveliness, timeouts, status).
struct Core {
    name: String,
    replica: Option<Replica>,
    st: MirrorStatus,
    in_error: bool,
    last_heard: Instant,
    /// An error that ends the mirror (the replica port could not be made or written).
    fatal: Option<anyhow::Error>,
}

impl Core {
    /// One Zenoh message of chunks.
    fn on_message(&mut self, bytes: &[u8], offset: Option<i64>) {
        self.last_heard = Instant::now();
        match wire::decode_batch(bytes) {
            Ok(chunks) => {
                for c in chunks {
                    if let Err(e) = on_chunk(&self.name, &mut self.replica, &mut self.st, c, offset) {
                        self.fatal.get_or_insert(e);
                        return;
                    }
                }
                if self.in_error {
                    if let Some(r) = &self.replica {
                        r.writer.set_state(State::Capturing, error_code::NONE, "");
                    }
                    self.in_error = false;
                    tracing::info!("source back: replica capturing again");
                }
            }
            Err(e) => {
                self.st.invalid_messages += 1;
                tracing::warn!("refused a message: {e}");
            }
        }
    }
}

fn lock(core: &Mutex<Core>) -> MutexGuard<'_, Core> {
    core.lock().unwrap_or_else(|e| e.into_inner())
}

/// The mirror's counters (status file and log).
#[derive(Clone, Debug, Default, Serialize)]
pub struct MirrorStatus {
    /// Replica port name.
    pub replica: String,
    /// Replica epoch (0 = none yet).
    pub replica_epoch: u64,
    /// Source epoch followed.
    pub source_epoch: u64,
    /// Newest replica frame.
    pub last_frame_index: u64,
    /// Chunks written with data.
    pub chunks_written: u64,
    /// Frames published as GAP for chunks that never arrived.
    pub gap_frames_lost: u64,
    /// Of those, frames the source side reported as not sent (its queue or its reader).
    pub gap_frames_source: u64,
    /// Chunks dropped for arriving late or twice.
    pub late_or_duplicate: u64,
    /// Messages refused by the decoder.
    pub invalid_messages: u64,
    /// Times the replica went into the error state (source unreachable or failed).
    pub outages: u64,
    /// Source CLOCK_MONOTONIC minus local CLOCK_MONOTONIC (ns), estimated.
    pub clock_offset_ns: Option<i64>,
    /// Uncertainty of that estimate (ns): half the best round trip.
    pub clock_uncertainty_ns: Option<u64>,
    /// Source clock rate relative to ours minus 1, in parts per million.
    pub clock_drift_ppm: Option<f64>,
    /// Replica state.
    pub state: String,
}

struct Replica {
    writer: Writer,
    source_epoch: u64,
    geometry: Geometry,
    instance: u64,
    expected: u64,
    last_source_lost: u64,
}

/// Runs `mirror` until SIGTERM/SIGINT.
pub fn run(o: MirrorOpts) -> Result<()> {
    let term = net::termination_flag()?;
    let name = o.name.clone().unwrap_or_else(|| format!("{}-{}", hostname(), o.source));
    let session = o.net.open()?;
    let clock = Arc::new(ClockEstimator::spawn(
        &session,
        o.net.key(&o.source, "clock"),
        Duration::from_secs_f64(o.probe_interval.max(0.01)),
    )?);
    let core = Arc::new(Mutex::new(Core {
        name: name.clone(),
        replica: None,
        st: MirrorStatus { replica: name.clone(), state: "idle".into(), ..Default::default() },
        in_error: false,
        last_heard: Instant::now(),
        fatal: None,
    }));
    let (chunk_core, chunk_clock) = (core.clone(), clock.clone());
    let chunks = session
        .declare_subscriber(o.net.key(&o.source, "chunks"))
        .callback(move |s| {
            let (offset, _) = chunk_clock.estimate();
            lock(&chunk_core).on_message(&s.payload().to_bytes(), offset);
        })
        .wait()
        .map_err(|e| anyhow!("subscribe to chunks: {e}"))?;
    let (tx, rx) = channel::<Event>();
    let state_tx = tx.clone();
    let _state = session
        .declare_subscriber(o.net.key(&o.source, "state"))
        .callback(move |s| {
            let _ = state_tx.send(Event::State(s.payload().to_bytes().into_owned()));
        })
        .wait()
        .map_err(|e| anyhow!("subscribe to state: {e}"))?;
    let _alive = session
        .liveliness()
        .declare_subscriber(o.net.key(&o.source, "alive"))
        .history(true)
        .callback(move |s| {
            let _ = tx.send(Event::Alive(s.kind() == SampleKind::Put));
        })
        .wait()
        .map_err(|e| anyhow!("liveliness subscriber: {e}"))?;

    let socket = bassclient::paths::socket_path(&name)?;
    crate::control::spawn_forwarder(&session, o.net.key(&o.source, "control"), &socket, term.clone())?;
    let timeout = Duration::from_secs_f64(o.timeout.max(0.1));
    let mut alive = false;
    let mut last_status = Instant::now() - Duration::from_secs(10);
    tracing::info!(replica = %name, source = %o.source, "mirroring");
    while !term.load(Ordering::Relaxed) {
        let ev = rx.recv_timeout(Duration::from_millis(100));
        let mut guard = lock(&core);
        let c = &mut *guard;
        if let Some(e) = c.fatal.take() {
            return Err(e);
        }
        match ev {
            Ok(Event::State(bytes)) => {
                c.last_heard = Instant::now();
                if let Ok(s) = serde_json::from_slice::<SourceState>(&bytes) {
                    on_source_state(&c.replica, &s, &mut c.in_error, &mut c.st);
                }
            }
            Ok(Event::Alive(a)) => {
                alive = a;
                if a {
                    c.last_heard = Instant::now();
                }
                tracing::info!(alive = a, "source liveliness");
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        if let Some(r) = &c.replica {
            r.writer.heartbeat();
            let silent = c.last_heard.elapsed() > timeout;
            if silent && !c.in_error && r.writer.state() == State::Capturing {
                let why =
                    if alive { "no data from the source" } else { "source unreachable (liveliness lost)" };
                r.writer.set_state(
                    State::Error,
                    error_code::DEVICE_LOST,
                    &format!("{why} for more than {:.1} s", timeout.as_secs_f64()),
                );
                c.in_error = true;
                c.st.outages += 1;
                tracing::warn!("{why}: replica in error");
            }
        }
        if last_status.elapsed() >= Duration::from_secs(1) {
            last_status = Instant::now();
            let (off, unc) = clock.estimate();
            c.st.clock_offset_ns = off;
            c.st.clock_uncertainty_ns = unc;
            c.st.clock_drift_ppm = clock.drift_ppm();
            if let Some(r) = &c.replica {
                c.st.last_frame_index = r.writer.last_frame_index();
                c.st.state = format!("{:?}", r.writer.state()).to_lowercase();
            }
            let st = c.st.clone();
            drop(guard);
            // Written without the lock: the chunk subscriber never waits for the disk.
            if let Some(p) = &o.status_file {
                let tmp = p.with_extension("tmp");
                std::fs::write(&tmp, serde_json::to_vec_pretty(&st)?).context("write the status file")?;
                std::fs::rename(&tmp, p).context("rename the status file")?;
            }
        }
    }
    drop(chunks);
    if let Some(r) = lock(&core).replica.take() {
        r.writer.set_state(State::Stopped, error_code::NONE, "mirror stopped");
        let _ = r.writer.remove();
    }
    tracing::info!("mirror: terminated");
    Ok(())
}

fn on_source_state(replica: &Option<Replica>, s: &SourceState, in_error: &mut bool, st: &mut MirrorStatus) {
    let Some(r) = replica else { return };
    if s.epoch != 0 && s.epoch != r.source_epoch {
        return; // another acquisition: its first chunk makes a new replica.
    }
    match s.state.as_str() {
        "error" | "gone" if !*in_error && r.writer.state() == State::Capturing => {
            let code = if s.error_code != 0 { s.error_code } else { error_code::DEVICE_LOST };
            let msg = if s.state == "gone" {
                "the source broker is gone".to_string()
            } else {
                format!("source: {}", s.message)
            };
            r.writer.set_state(State::Error, code, &msg);
            *in_error = true;
            st.outages += 1;
            tracing::warn!("{msg}: replica in error");
        }
        "stopped" if r.writer.state() == State::Capturing => r.writer.stop(),
        _ => {}
    }
}

fn on_chunk(
    name: &str,
    replica: &mut Option<Replica>,
    st: &mut MirrorStatus,
    c: wire::Chunk,
    offset: Option<i64>,
) -> Result<()> {
    let h = c.header;
    let geometry = Geometry {
        channels: u32::from(h.channels),
        sample_rate: h.sample_rate,
        frames_per_chunk: h.frames,
        chunks_on_port: h.chunks_on_port,
    };
    let nfpc = u64::from(h.frames);
    let same = replica.as_ref().is_some_and(|r| r.source_epoch == h.epoch && r.geometry == geometry);
    if !same {
        // A new acquisition upstream (or the first chunk): a new replica port.
        let params = PortParams {
            geometry: geometry.clone(),
            device: format!("bass-bridge mirror of {}", h.epoch),
            group: None,
        };
        if let Some(old) = replica.take() {
            drop(old.writer);
        }
        let mut writer = Writer::create(name, &params).context("create the replica port")?;
        writer.start_at(h.first_frame).context("start the replica at the source's frame")?;
        tracing::info!(epoch = h.epoch, replica_epoch = writer.epoch(), first = h.first_frame, "new replica");
        st.replica_epoch = writer.epoch();
        st.source_epoch = h.epoch;
        *replica = Some(Replica {
            writer,
            source_epoch: h.epoch,
            geometry,
            instance: h.instance,
            expected: h.first_frame,
            last_source_lost: h.source_lost,
        });
    }
    let Some(r) = replica.as_mut() else { return Ok(()) };
    if r.instance != h.instance {
        tracing::info!(
            instance = format!("{:016x}", h.instance),
            "new serve instance, same epoch: the port is kept"
        );
        r.instance = h.instance;
        r.last_source_lost = 0;
    }
    if h.first_frame < r.expected {
        st.late_or_duplicate += 1;
        return Ok(());
    }
    let mono = match offset {
        Some(off) if h.mono_ns != 0 => (h.mono_ns as i64 - off).max(1) as u64,
        _ => 0,
    };
    let meta = ChunkMeta { mono_ns: mono, realtime_ns: h.realtime_ns, flags: chunk_flags::TIME_ESTIMATED };
    if h.first_frame > r.expected {
        let missing = h.first_frame - r.expected;
        // The source's cumulative count says how many of them it never sent.
        let from_source = h.source_lost.saturating_sub(r.last_source_lost).min(missing);
        r.writer.publish_lost(
            missing,
            ChunkMeta { mono_ns: 0, realtime_ns: 0, flags: chunk_flags::TIME_ESTIMATED },
        )?;
        st.gap_frames_lost += missing;
        st.gap_frames_source += from_source;
    }
    r.last_source_lost = h.source_lost;
    let mut flags = meta.flags;
    if h.flags & wire::flags::DISCONTINUITY != 0 || h.flags & wire::flags::SOURCE_LOSS != 0 {
        flags |= chunk_flags::DISCONTINUITY;
    }
    if h.flags & wire::flags::GAP != 0 {
        r.writer.publish(Source::Zeros, ChunkMeta { flags: flags | chunk_flags::GAP, ..meta })?;
    } else {
        r.writer.publish(Source::Interleaved(&c.samples), ChunkMeta { flags, ..meta })?;
    }
    r.expected = h.first_frame + nfpc;
    st.chunks_written += 1;
    Ok(())
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_owned())
        .unwrap_or_else(|_| "remote".into())
}
