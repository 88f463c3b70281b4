//! Several devices in one acquisition (docs/multi-device.md): the master's capture thread
//! assembles its chunks as for one device; every follower has a capture thread of its own;
//! `align::Aligner` resamples each follower onto the master's frames; whichever thread's
//! chunk completes a master chunk publishes it, with the master's channels first and each
//! follower's after them.
//!
//! ```text
//!  master thread ── chunk ──► Aligner (one lock) ◄── chunks ── follower thread(s)
//!                                │ pop: a master chunk with every follower on its frames
//!                                ▼
//!         Writer::publish(master ch | follower 1 ch | ...; missing/unaligned channel masks)
//! ```
//!
//! Per chunk and follower: frames the aligner could not fill (the follower's xrun, unplug,
//! late or absent frames) are zeros and set the follower's bits in `missing_channels`; a
//! follower not locked sets its bits in `unaligned_channels`. A master gap (an xrun) is a
//! whole-chunk GAP as with one device; the aligner starts again after it and the followers
//! re-lock. A follower that fails is reopened every [`REOPEN_NS`] until it comes back.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use align::{Aligner, Chunk, Config};
use bassport::control::DeviceStatus;
use bassport::format::error_code;
use bassport::sys::monotonic_ns;
use bassport::{ChunkMeta, Source};

use super::Shared;
use crate::device::{sleep_until, Capture, ReadEvent};

/// Opens a follower device afresh (its first open, and after a failure its device cannot
/// recover from in place).
pub type Opener = Box<dyn Fn() -> Result<Box<dyn Capture>, String> + Send>;

/// A follower of an acquisition, before its thread starts.
pub struct FollowerSpec {
    /// Its name.
    pub name: String,
    /// Its channels.
    pub channels: usize,
    /// How to open it.
    pub open: Opener,
}

/// How long a follower's error estimate must stay below the lock threshold, seconds.
pub const LOCK_HOLD_S: f64 = 0.5;

/// How often a lost follower is reopened.
pub const REOPEN_NS: u64 = 250_000_000;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum FState {
    Waiting,
    Aligning,
    Locked,
    Lost,
}

/// A follower's counters and state for Status.
struct FStats {
    name: String,
    first_channel: u32,
    channels: u32,
    state: FState,
    ratio_ppm: f64,
    error: f64,
    locks: u64,
    xruns: u64,
    unplugs: u64,
    missing_frames: u64,
    unaligned_frames: u64,
    seen_valid: bool,
    lost: bool,
}

impl FStats {
    fn mask(&self) -> u64 {
        let ones = if self.channels >= 64 { u64::MAX } else { (1u64 << self.channels) - 1 };
        ones.checked_shl(self.first_channel).unwrap_or(0)
    }
}

struct Inner {
    aligner: Aligner,
    cfg: Config,
    /// Master chunks given to the aligner, not yet published: samples and stamps.
    pending: VecDeque<(Vec<i32>, ChunkMeta)>,
    stats: Vec<FStats>,
    out: Vec<i32>,
}

/// The shared state of a several-device acquisition.
pub struct Multi {
    inner: Mutex<Inner>,
    master: String,
    master_channels: usize,
    channels: usize,
    nfpc: usize,
}

impl Multi {
    /// The aligner of an acquisition of `master` and `followers` (None without followers).
    pub fn for_acquisition(
        master: &str,
        master_channels: u32,
        followers: &[FollowerSpec],
        g: &bassport::Geometry,
    ) -> std::io::Result<Option<Arc<Multi>>> {
        if followers.is_empty() {
            return Ok(None);
        }
        let (mch, nfpc) = (master_channels as usize, g.frames_per_chunk as usize);
        let m = Multi::new(master, mch, followers, g.sample_rate, nfpc).map_err(std::io::Error::other)?;
        Ok(Some(Arc::new(m)))
    }

    /// For a master `master` of `master_channels` and `followers`, chunks of `nfpc` frames
    /// at `rate` Hz.
    pub fn new(
        master: &str,
        master_channels: usize,
        followers: &[FollowerSpec],
        rate: u32,
        nfpc: usize,
    ) -> Result<Multi, String> {
        let mut cfg = Config::new(f64::from(rate), master_channels);
        cfg.max_chunk_frames = cfg.max_chunk_frames.max(nfpc);
        // The aligner's default hold. It was 1.5 s while the seed's integrating controller
        // swung through zero just after the first lock (docs/multi-device.md, "Figures").
        cfg.lock_hold_s = LOCK_HOLD_S;
        let channels: Vec<usize> = followers.iter().map(|f| f.channels).collect();
        let aligner = Aligner::new(cfg, &channels).map_err(|e| e.to_string())?;
        let mut first = master_channels;
        let stats = followers
            .iter()
            .map(|f| {
                let s = FStats {
                    name: f.name.clone(),
                    first_channel: first as u32,
                    channels: f.channels as u32,
                    state: FState::Waiting,
                    ratio_ppm: 0.0,
                    error: 0.0,
                    locks: 0,
                    xruns: 0,
                    unplugs: 0,
                    missing_frames: 0,
                    unaligned_frames: 0,
                    seen_valid: false,
                    lost: false,
                };
                first += f.channels;
                s
            })
            .collect();
        let inner = Inner { aligner, cfg, pending: VecDeque::new(), stats, out: Vec::new() };
        Ok(Multi { inner: Mutex::new(inner), master: master.into(), master_channels, channels: first, nfpc })
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A master chunk (`samples`: the master's channels): aligned and published once every
    /// follower has its frames. A GAP chunk (`gap`) or one after a master overrun
    /// (`discontinuity`) first publishes what is pending and starts the aligner again.
    pub fn master_chunk(
        &self,
        shared: &Shared,
        samples: &[i32],
        gap: bool,
        discontinuity: bool,
        meta: ChunkMeta,
    ) {
        let mut inner = self.lock();
        if gap || discontinuity {
            self.restart(&mut inner, shared);
        }
        if gap {
            let mut meta = meta;
            meta.missing_channels = u64::MAX >> (64 - self.channels.min(64));
            publish(shared, Source::Zeros, meta);
            return;
        }
        let chunk = Chunk { samples, frames: self.nfpc, stamp_ns: meta.mono_ns, after_gap: false };
        if let Err(e) = inner.aligner.push_master(chunk) {
            tracing::warn!("aligner: master chunk refused: {e}; starting it again");
            self.restart(&mut inner, shared);
            let _ = inner.aligner.push_master(chunk);
        }
        inner.pending.push_back((samples.to_vec(), meta));
        self.drain(&mut inner, shared);
    }

    /// A chunk of follower `i` (its stamp, and whether frames were lost before it).
    fn follower_chunk(
        &self,
        shared: &Shared,
        i: usize,
        samples: &[i32],
        frames: usize,
        stamp_ns: u64,
        after_gap: bool,
    ) {
        let mut inner = self.lock();
        let chunk = Chunk { samples, frames, stamp_ns, after_gap };
        if let Err(e) = inner.aligner.push_follower(i, chunk) {
            tracing::warn!(follower = i, "aligner: follower chunk refused: {e}");
        }
        if inner.stats[i].state == FState::Waiting {
            inner.stats[i].state = FState::Aligning;
        }
        self.drain(&mut inner, shared);
    }

    /// Publishes every master chunk the aligner has finished.
    fn drain(&self, inner: &mut Inner, shared: &Shared) {
        while let Some(a) = inner.aligner.pop() {
            let Some((master, mut meta)) = inner.pending.pop_front() else { break };
            let (mch, n) = (self.master_channels, a.frames);
            let mut out = std::mem::take(&mut inner.out);
            out.clear();
            out.resize(n * self.channels, 0);
            for (j, frame) in out.chunks_exact_mut(self.channels).enumerate() {
                frame[..mch].copy_from_slice(&master[j * mch..(j + 1) * mch]);
            }
            for (f, s) in a.followers.iter().zip(inner.stats.iter_mut()) {
                let (c0, ch) = (s.first_channel as usize, s.channels as usize);
                for (j, frame) in out.chunks_exact_mut(self.channels).enumerate() {
                    frame[c0..c0 + ch].copy_from_slice(&f.samples[j * ch..(j + 1) * ch]);
                }
                let invalid = f.valid.iter().filter(|v| !**v).count() as u64;
                s.seen_valid |= invalid < n as u64;
                if invalid > 0 {
                    meta.missing_channels |= s.mask();
                    if s.seen_valid {
                        s.missing_frames += invalid;
                    }
                }
                if !f.locked {
                    meta.unaligned_channels |= s.mask();
                    s.unaligned_frames += n as u64;
                }
                if f.locked && s.state != FState::Locked {
                    s.locks += 1;
                }
                s.state = match (s.lost, f.locked, s.state) {
                    (true, _, _) => FState::Lost,
                    (false, true, _) => FState::Locked,
                    (false, false, FState::Waiting) => FState::Waiting,
                    _ => FState::Aligning,
                };
                if f.step > 0.0 {
                    s.ratio_ppm = (f.step - 1.0) * 1e6;
                }
                s.error = if f.error_estimate.is_finite() { f.error_estimate } else { 0.0 };
            }
            publish(shared, Source::Interleaved(&out), meta);
            inner.out = out;
        }
    }

    /// Publishes what is pending with every follower missing and starts the aligner again.
    fn restart(&self, inner: &mut Inner, shared: &Shared) {
        let all = inner.stats.iter().fold(0, |m, s| m | s.mask());
        while let Some((master, mut meta)) = inner.pending.pop_front() {
            let mut out = vec![0; self.nfpc * self.channels];
            for (j, frame) in out.chunks_exact_mut(self.channels).enumerate() {
                frame[..self.master_channels]
                    .copy_from_slice(&master[j * self.master_channels..(j + 1) * self.master_channels]);
            }
            meta.missing_channels |= all;
            meta.unaligned_channels |= all;
            publish(shared, Source::Interleaved(&out), meta);
        }
        let channels: Vec<usize> = inner.stats.iter().map(|s| s.channels as usize).collect();
        match Aligner::new(inner.cfg, &channels) {
            Ok(a) => inner.aligner = a,
            Err(e) => tracing::error!("aligner: cannot start again: {e}"),
        }
        for s in &mut inner.stats {
            if s.state == FState::Locked {
                s.state = FState::Aligning;
            }
        }
    }

    fn update(&self, i: usize, f: impl FnOnce(&mut FStats)) {
        f(&mut self.lock().stats[i]);
    }

    /// Status rows: the master (with the port's `xruns` and `gap_frames`), then the followers.
    pub fn status(&self, master_xruns: u64, master_gap_frames: u64) -> Vec<DeviceStatus> {
        let inner = self.lock();
        let mut v = vec![DeviceStatus {
            name: self.master.clone(),
            role: "master".into(),
            channels: self.master_channels as u32,
            state: "master".into(),
            xruns: master_xruns,
            missing_frames: master_gap_frames,
            ..DeviceStatus::default()
        }];
        v.extend(inner.stats.iter().map(|s| {
            DeviceStatus {
                name: s.name.clone(),
                role: "follower".into(),
                first_channel: s.first_channel,
                channels: s.channels,
                state: match s.state {
                    FState::Waiting => "waiting",
                    FState::Aligning => "aligning",
                    FState::Locked => "locked",
                    FState::Lost => "lost",
                }
                .into(),
                ratio_ppm: s.ratio_ppm,
                error_estimate: s.error,
                locks: s.locks,
                xruns: s.xruns,
                unplugs: s.unplugs,
                missing_frames: s.missing_frames,
                unaligned_frames: s.unaligned_frames,
            }
        }));
        v
    }
}

fn publish(shared: &Shared, src: Source<'_>, meta: ChunkMeta) {
    let mut w = shared.writer();
    if shared.ended.load(std::sync::atomic::Ordering::Acquire) || shared.stop.is_set() {
        return;
    }
    if let Err(e) = w.publish(src, meta) {
        drop(w);
        shared.fail(error_code::INTERNAL, &format!("publishing a chunk failed: {e}"));
    }
}

/// Starts the followers' capture threads (none without an aligner).
pub fn spawn_followers(
    shared: &Arc<Shared>,
    multi: Option<&Arc<Multi>>,
    specs: Vec<FollowerSpec>,
    period: usize,
    rt_priority: i32,
) -> std::io::Result<Vec<JoinHandle<()>>> {
    let Some(multi) = multi else { return Ok(Vec::new()) };
    let mut v = Vec::new();
    for (i, spec) in specs.into_iter().enumerate() {
        let (shared, multi) = (shared.clone(), multi.clone());
        v.push(std::thread::Builder::new().name(format!("bassd-follow{}", i + 1)).spawn(move || {
            super::try_realtime(rt_priority);
            crate::device::precise_timers();
            follower_loop(&shared, &multi, i, &spec, period);
        })?);
    }
    Ok(v)
}

/// Waits up to `timeout` for the followers' threads (signalled to stop); a thread blocked
/// in its device is left behind.
pub fn join_followers(threads: Vec<JoinHandle<()>>, timeout: Duration) {
    let deadline = monotonic_ns() + timeout.as_nanos() as u64;
    for t in threads {
        while !t.is_finished() && monotonic_ns() < deadline {
            std::thread::sleep(Duration::from_millis(2));
        }
        if t.is_finished() {
            let _ = t.join();
        } else {
            tracing::warn!("a follower's capture thread is still blocked in its device; leaving it behind");
        }
    }
}

/// Opens (or reopens) follower `i` until it starts or the acquisition stops.
fn open_follower(
    shared: &Shared,
    multi: &Multi,
    i: usize,
    spec: &FollowerSpec,
    dev: Option<Box<dyn Capture>>,
) -> Option<Box<dyn Capture>> {
    let mut dev = dev;
    let mut said = false;
    while !shared.stop.is_set() {
        let opened = match dev.as_mut().and_then(|d| d.reopen()) {
            Some(r) => r.map(|()| dev.take()),
            None => (spec.open)().and_then(|mut d| d.start().map(|()| Some(d))),
        };
        match opened {
            Ok(Some(d)) => {
                tracing::info!(follower = %spec.name, "follower device (re)started");
                multi.update(i, |s| s.lost = false);
                return Some(d);
            }
            Ok(None) => {}
            Err(e) => {
                if !said {
                    tracing::warn!(follower = %spec.name, "follower device not available: {e}; retrying");
                    said = true;
                }
                multi.update(i, |s| {
                    s.lost = true;
                    s.state = FState::Lost;
                });
            }
        }
        if !sleep_until(monotonic_ns() + REOPEN_NS, &shared.stop) {
            break;
        }
    }
    None
}

fn follower_loop(shared: &Shared, multi: &Multi, i: usize, spec: &FollowerSpec, period: usize) {
    let mut buf = vec![0i32; period * spec.channels];
    let mut dev = open_follower(shared, multi, i, spec, None);
    let mut after_gap = false;
    while let Some(d) = dev.as_mut() {
        if shared.stop.is_set() {
            break;
        }
        match d.read(&mut buf, period, &shared.stop) {
            ReadEvent::Frames { frames, first_mono_ns, .. } => {
                tracing::trace!(follower = i, frames, first_mono_ns, "follower frames");
                let samples = &buf[..frames * spec.channels];
                multi.follower_chunk(
                    shared,
                    i,
                    samples,
                    frames,
                    first_mono_ns,
                    std::mem::take(&mut after_gap),
                );
            }
            ReadEvent::Xrun => {
                multi.update(i, |s| s.xruns += 1);
                after_gap = true;
            }
            ReadEvent::Failed { message, .. } | ReadEvent::Ended { message, .. } => {
                tracing::warn!(follower = %spec.name, "follower device lost: {message}; the acquisition goes on");
                multi.update(i, |s| {
                    s.unplugs += 1;
                    s.lost = true;
                    s.state = FState::Lost;
                });
                after_gap = true;
                dev = open_follower(shared, multi, i, spec, dev.take());
            }
            ReadEvent::Stopped => break,
            ReadEvent::Idle | ReadEvent::Pending | ReadEvent::Chunk(_) => {}
        }
    }
}
