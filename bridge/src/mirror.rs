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
use std::sync::mpsc::{channel, RecvTimeoutError, Sender};
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

enum Event {
    Chunk(Vec<u8>),
    State(Vec<u8>),
    Alive(bool),
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
    let (tx, rx) = channel::<Event>();
    let sub = |leaf: &str, wrap: fn(Vec<u8>) -> Event, tx: Sender<Event>| {
        session
            .declare_subscriber(o.net.key(&o.source, leaf))
            .callback(move |s| {
                let _ = tx.send(wrap(s.payload().to_bytes().into_owned()));
            })
            .wait()
            .map_err(|e| anyhow!("subscribe to {leaf}: {e}"))
    };
    let _chunks = sub("chunks", Event::Chunk, tx.clone())?;
    let _state = sub("state", Event::State, tx.clone())?;
    let alive_tx = tx.clone();
    let _alive = session
        .liveliness()
        .declare_subscriber(o.net.key(&o.source, "alive"))
        .history(true)
        .callback(move |s| {
            let _ = alive_tx.send(Event::Alive(s.kind() == SampleKind::Put));
        })
        .wait()
        .map_err(|e| anyhow!("liveliness subscriber: {e}"))?;
    let clock = ClockEstimator::spawn(
        &session,
        o.net.key(&o.source, "clock"),
        Duration::from_secs_f64(o.probe_interval.max(0.01)),
    )?;

    let socket = bassclient::paths::socket_path(&name)?;
    crate::control::spawn_forwarder(&session, o.net.key(&o.source, "control"), &socket, term.clone())?;
    let timeout = Duration::from_secs_f64(o.timeout.max(0.1));
    let mut st = MirrorStatus { replica: name.clone(), state: "idle".into(), ..Default::default() };
    let mut replica: Option<Replica> = None;
    let mut alive = false;
    let mut last_heard = Instant::now();
    let mut last_status = Instant::now() - Duration::from_secs(10);
    let mut in_error = false;
    tracing::info!(replica = %name, source = %o.source, "mirroring");
    while !term.load(Ordering::Relaxed) {
        let ev = rx.recv_timeout(Duration::from_millis(100));
        let (offset, _) = clock.estimate();
        match ev {
            Ok(Event::Chunk(bytes)) => {
                last_heard = Instant::now();
                match wire::decode_batch(&bytes) {
                    Ok(chunks) => {
                        for c in chunks {
                            on_chunk(&name, &mut replica, &mut st, c, offset)?;
                        }
                        if in_error {
                            if let Some(r) = &replica {
                                r.writer.set_state(State::Capturing, error_code::NONE, "");
                            }
                            in_error = false;
                            tracing::info!("source back: replica capturing again");
                        }
                    }
                    Err(e) => {
                        st.invalid_messages += 1;
                        tracing::warn!("refused a message: {e}");
                    }
                }
            }
            Ok(Event::State(bytes)) => {
                last_heard = Instant::now();
                if let Ok(s) = serde_json::from_slice::<SourceState>(&bytes) {
                    on_source_state(&replica, &s, &mut in_error, &mut st);
                }
            }
            Ok(Event::Alive(a)) => {
                alive = a;
                if a {
                    last_heard = Instant::now();
                }
                tracing::info!(alive = a, "source liveliness");
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        if let Some(r) = &replica {
            r.writer.heartbeat();
            let silent = last_heard.elapsed() > timeout;
            if (silent || !alive && last_heard.elapsed() > timeout)
                && !in_error
                && r.writer.state() == State::Capturing
            {
                let why =
                    if alive { "no data from the source" } else { "source unreachable (liveliness lost)" };
                r.writer.set_state(
                    State::Error,
                    error_code::DEVICE_LOST,
                    &format!("{why} for more than {:.1} s", timeout.as_secs_f64()),
                );
                in_error = true;
                st.outages += 1;
                tracing::warn!("{why}: replica in error");
            }
        }
        if last_status.elapsed() >= Duration::from_secs(1) {
            last_status = Instant::now();
            let (off, unc) = clock.estimate();
            st.clock_offset_ns = off;
            st.clock_uncertainty_ns = unc;
            st.clock_drift_ppm = clock.drift_ppm();
            if let Some(r) = &replica {
                st.last_frame_index = r.writer.last_frame_index();
                st.state = format!("{:?}", r.writer.state()).to_lowercase();
            }
            if let Some(p) = &o.status_file {
                let tmp = p.with_extension("tmp");
                std::fs::write(&tmp, serde_json::to_vec_pretty(&st)?).context("write the status file")?;
                std::fs::rename(&tmp, p).context("rename the status file")?;
            }
        }
    }
    if let Some(r) = replica {
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
