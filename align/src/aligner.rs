//! The aligner: master and follower chunks in, each follower on the master's frames out.
//!
//! The master's frames are the frame index. Each follower card's frames form *runs*
//! (from its first chunk, or from the first chunk after a gap, to its last before one),
//! each with its own [`TimeLine`], resampler [`Stage`] and [`RateControl`]. For master
//! frame `k` the follower position the time lines give is
//! `p(k) = follower_line.frame_at(master_line.time_of(k))`; per master chunk the
//! resampler's step is the feed-forward `(p(k+n) - p(k))/n` times the controller's
//! correction, the controller driving `p(k)` minus the resampler's exact position to zero.
//! A run starts *aligned*: a first, discarded call of the resampler with a step chosen so
//! that its next output frame lies exactly at `p(k)`, the first master frame whose kernel
//! lies wholly on the run's frames.
//!
//! A follower frame is *valid* when the resampler's kernel (half-length `L/2` either side
//! of its position) lies wholly on frames the card delivered; a gap therefore marks not
//! valid exactly the master frames whose position lies within `L/2 + 1` frames of the
//! missing ones, and the run after it starts, aligned, on its own. A follower is *locked*
//! once its error estimate (controller error plus the lines' uncertainty, in samples) has
//! stayed below `lock_threshold` for `lock_hold_s`; it loses the lock above twice that,
//! and with every gap.

use std::collections::VecDeque;

use crate::control::RateControl;
use crate::resample::{Design, Stage};
use crate::timeline::TimeLine;
use crate::{Chunk, Error};

/// The aligner's parameters.
#[derive(Clone, Copy, Debug)]
pub struct Config {
    /// Nominal rate of every card, Hz.
    pub nominal_hz: f64,
    /// Channels of the master card.
    pub master_channels: usize,
    /// Longest master chunk, frames (at least the sinc length + 8).
    pub max_chunk_frames: usize,
    /// Stamps a time line is fitted over, seconds.
    pub window_s: f64,
    /// The controller's time constant, seconds (control.rs).
    pub control_period_s: f64,
    /// Error estimate below which a follower counts towards lock, samples.
    pub lock_threshold: f64,
    /// How long the estimate must stay below the threshold, seconds.
    pub lock_hold_s: f64,
    /// How long after a master frame's time the aligner waits for a follower's frames
    /// before marking them not valid, seconds.
    pub gap_timeout_s: f64,
    /// A follower stamp this far from its line's prediction starts a new run (frames were
    /// lost without a mark), seconds.
    pub gap_jump_s: f64,
    /// The controller is on (off only to show what it does).
    pub controller: bool,
    /// The resampler.
    pub design: Design,
}

impl Config {
    /// The defaults for cards of `nominal_hz` and a master of `master_channels`.
    pub fn new(nominal_hz: f64, master_channels: usize) -> Config {
        Config {
            nominal_hz,
            master_channels,
            max_chunk_frames: 1024,
            window_s: 4.0,
            control_period_s: 0.25,
            lock_threshold: 0.5,
            lock_hold_s: 0.5,
            gap_timeout_s: 0.05,
            gap_jump_s: 0.02,
            controller: true,
            design: Design::standard(),
        }
    }

    fn validate(&self) -> Result<(), Error> {
        let bad = |name, value: f64, why| Err(Error::Config { name, value, why });
        if !(1000.0..=1e6).contains(&self.nominal_hz) {
            return bad("nominal_hz", self.nominal_hz, "1000 to 1e6 Hz");
        }
        if self.master_channels == 0 {
            return bad("master_channels", 0.0, "at least 1");
        }
        if self.max_chunk_frames < self.design.sinc_len + 8 {
            return bad("max_chunk_frames", self.max_chunk_frames as f64, "at least the sinc length + 8");
        }
        for (name, v) in [
            ("window_s", self.window_s),
            ("control_period_s", self.control_period_s),
            ("lock_threshold", self.lock_threshold),
            ("gap_timeout_s", self.gap_timeout_s),
            ("gap_jump_s", self.gap_jump_s),
        ] {
            if v.is_nan() || v <= 0.0 || v.is_infinite() {
                return bad(name, v, "positive and finite");
            }
        }
        if self.lock_hold_s.is_nan() || self.lock_hold_s < 0.0 {
            return bad("lock_hold_s", self.lock_hold_s, "not negative");
        }
        Ok(())
    }
}

/// One follower on one master chunk.
#[derive(Clone, Debug)]
pub struct FollowerOutput {
    /// Interleaved left-justified S32 samples on the master's frames (0 where not valid).
    pub samples: Vec<i32>,
    /// Per frame: the sample is the follower's signal (see the module doc).
    pub valid: Vec<bool>,
    /// The follower is locked (see the module doc).
    pub locked: bool,
    /// The alignment error estimate at the chunk's first frame, samples (infinite without
    /// a run).
    pub error_estimate: f64,
    /// The resampler's step: follower frames per master frame (0 without a run).
    pub step: f64,
    /// The controller's error at the chunk's first frame: the lines' target position
    /// minus the resampler's, samples (NaN without a run).
    pub controller_error: f64,
}

/// Every follower on one master chunk.
#[derive(Clone, Debug)]
pub struct Aligned {
    /// Master frame index of the chunk's first frame.
    pub master_frame: u64,
    /// Frames in the chunk.
    pub frames: usize,
    /// One output per follower, in the order given to [`Aligner::new`].
    pub followers: Vec<FollowerOutput>,
}

/// A contiguous stretch of one follower's frames.
struct Run {
    line: TimeLine,
    fifo: Vec<VecDeque<f64>>,
    /// Run frame of `fifo[..][0]`.
    fifo_start: u64,
    /// Run frames delivered.
    received: u64,
    /// The resampler and the run frame of its first input frame, once started.
    stage: Option<(Stage, u64)>,
    ctl: RateControl,
    /// No more frames will come: the resampler is fed zeros past `received`.
    closed: bool,
}

/// What one run contributed to a chunk.
struct Rendered {
    /// Position error at the first frame rendered, and the lines' uncertainty, samples.
    error: f64,
    uncertainty: f64,
    step: f64,
}

struct Follower {
    channels: usize,
    run: Option<Run>,
    closing: VecDeque<Run>,
    good_frames: u64,
    locked: bool,
}

/// Aligns followers to a master; see the module doc.
pub struct Aligner {
    cfg: Config,
    origin_ns: Option<u64>,
    now_s: f64,
    master: Option<TimeLine>,
    master_frames: u64,
    queue: VecDeque<(u64, usize)>,
    followers: Vec<Follower>,
    scratch: Vec<Vec<f64>>,
}

impl Aligner {
    /// An aligner with `cfg` for followers of `follower_channels` channels each.
    pub fn new(cfg: Config, follower_channels: &[usize]) -> Result<Aligner, Error> {
        cfg.validate()?;
        if let Some(&bad) = follower_channels.iter().find(|&&c| c == 0) {
            return Err(Error::Config { name: "follower_channels", value: bad as f64, why: "at least 1" });
        }
        let followers = follower_channels
            .iter()
            .map(|&channels| Follower {
                channels,
                run: None,
                closing: VecDeque::new(),
                good_frames: 0,
                locked: false,
            })
            .collect();
        Ok(Aligner {
            cfg,
            origin_ns: None,
            now_s: f64::NEG_INFINITY,
            master: None,
            master_frames: 0,
            queue: VecDeque::new(),
            followers,
            scratch: Vec::new(),
        })
    }

    fn see(&mut self, stamp_ns: u64) -> u64 {
        let origin = *self.origin_ns.get_or_insert(stamp_ns);
        self.now_s = self.now_s.max((stamp_ns as f64 - origin as f64) * 1e-9);
        origin
    }

    /// Takes a master chunk.
    pub fn push_master(&mut self, chunk: Chunk<'_>) -> Result<(), Error> {
        check_shape(&chunk, self.cfg.master_channels)?;
        if chunk.frames > self.cfg.max_chunk_frames {
            return Err(Error::ChunkTooLong { frames: chunk.frames, max: self.cfg.max_chunk_frames });
        }
        if chunk.after_gap && self.master.is_some() {
            return Err(Error::MasterGap { master_frame: self.master_frames });
        }
        let origin = self.see(chunk.stamp_ns);
        let (hz, window) = (self.cfg.nominal_hz, self.cfg.window_s);
        let line = self.master.get_or_insert_with(|| TimeLine::new(hz, window, origin));
        line.push(self.master_frames as f64, chunk.stamp_ns);
        self.queue.push_back((self.master_frames, chunk.frames));
        self.master_frames += chunk.frames as u64;
        Ok(())
    }

    /// Takes a chunk of follower `index`.
    pub fn push_follower(&mut self, index: usize, chunk: Chunk<'_>) -> Result<(), Error> {
        let count = self.followers.len();
        let channels = self.followers.get(index).ok_or(Error::NoSuchFollower { index, count })?.channels;
        check_shape(&chunk, channels)?;
        let origin = self.see(chunk.stamp_ns);
        let cfg = self.cfg;
        let f = &mut self.followers[index];
        let t = (chunk.stamp_ns as f64 - origin as f64) * 1e-9;
        let jumped = f.run.as_ref().is_some_and(|r| {
            r.line.time_of(r.received as f64).is_some_and(|p| (t - p).abs() > cfg.gap_jump_s)
        });
        let closed = f.run.as_ref().is_some_and(|r| r.closed);
        if chunk.after_gap || jumped || closed {
            if let Some(mut old) = f.run.take() {
                old.closed = true;
                f.closing.push_back(old);
            }
        }
        let run = f.run.get_or_insert_with(|| {
            f.good_frames = 0;
            f.locked = false;
            Run {
                line: TimeLine::new(cfg.nominal_hz, cfg.window_s, origin),
                fifo: vec![VecDeque::new(); channels],
                fifo_start: 0,
                received: 0,
                stage: None,
                ctl: RateControl::new(),
                closed: false,
            }
        });
        run.line.push(run.received as f64, chunk.stamp_ns);
        for frame in chunk.samples.chunks_exact(channels) {
            for (q, &s) in run.fifo.iter_mut().zip(frame) {
                q.push_back(f64::from(s) / crate::sim::FULL_SCALE);
            }
        }
        run.received += chunk.frames as u64;
        Ok(())
    }

    /// The next aligned master chunk, once every follower has its frames or has been
    /// waited for `gap_timeout_s`.
    pub fn pop(&mut self) -> Option<Aligned> {
        let &(k, n) = self.queue.front()?;
        let master = self.master.as_ref()?;
        let end_time = master.time_of((k + n as u64) as f64)?;
        let timed_out = self.now_s - end_time > self.cfg.gap_timeout_s;
        for f in &mut self.followers {
            if !f.ready(master, k, n, timed_out, self.now_s, &self.cfg) {
                return None;
            }
        }
        self.queue.pop_front();
        let mut out =
            Aligned { master_frame: k, frames: n, followers: Vec::with_capacity(self.followers.len()) };
        for f in &mut self.followers {
            out.followers.push(f.render(master, k, n, &self.cfg, &mut self.scratch));
        }
        Some(out)
    }
}

fn check_shape(chunk: &Chunk<'_>, channels: usize) -> Result<(), Error> {
    if chunk.frames.checked_mul(channels) != Some(chunk.samples.len()) {
        return Err(Error::ChunkShape { frames: chunk.frames, channels, samples: chunk.samples.len() });
    }
    Ok(())
}

/// The run positions of master frames `k` and `k + n`.
fn positions(master: &TimeLine, run: &Run, k: u64, n: usize) -> Option<(f64, f64)> {
    let p = |f: u64| run.line.frame_at(master.time_of(f as f64)?);
    Some((p(k)?, p(k + n as u64)?))
}

impl Follower {
    /// Whether the master chunk `(k, n)` can be rendered now; closes a run that stopped
    /// delivering for longer than the timeout.
    fn ready(
        &mut self,
        master: &TimeLine,
        k: u64,
        n: usize,
        timed_out: bool,
        now: f64,
        cfg: &Config,
    ) -> bool {
        let Some(run) = self.run.as_mut() else { return timed_out };
        if run.closed {
            return true;
        }
        let Some((_, p1)) = positions(master, run, k, n) else { return timed_out };
        let need = (p1 + 1.5 * cfg.design.sinc_len as f64 + 4.0).ceil();
        if run.received as f64 >= need {
            return true;
        }
        let due = run.line.time_of(need).unwrap_or(f64::NEG_INFINITY);
        if now - due <= cfg.gap_timeout_s {
            return false;
        }
        if let Some(mut old) = self.run.take() {
            old.closed = true;
            self.closing.push_back(old);
        }
        true
    }

    fn render(
        &mut self,
        master: &TimeLine,
        k: u64,
        n: usize,
        cfg: &Config,
        scratch: &mut Vec<Vec<f64>>,
    ) -> FollowerOutput {
        let ch = self.channels;
        let mut out = FollowerOutput {
            samples: vec![0; n * ch],
            valid: vec![false; n],
            locked: false,
            error_estimate: f64::INFINITY,
            step: 0.0,
            controller_error: f64::NAN,
        };
        let mut i = 0;
        while i < self.closing.len() {
            let finished = self.closing[i].render(master, k, n, cfg, &mut out, scratch).is_none();
            if finished {
                self.closing.remove(i);
            } else {
                i += 1;
            }
        }
        let mut rendered = None;
        if let Some(run) = self.run.as_mut() {
            rendered = run.render(master, k, n, cfg, &mut out, scratch).flatten();
        }
        match rendered {
            Some(r) => {
                out.error_estimate = r.error.abs() + r.uncertainty;
                out.step = r.step;
                out.controller_error = r.error;
                if out.error_estimate < cfg.lock_threshold {
                    self.good_frames += n as u64;
                } else {
                    self.good_frames = 0;
                }
                if out.error_estimate > 2.0 * cfg.lock_threshold {
                    self.locked = false;
                }
                if self.good_frames as f64 >= cfg.lock_hold_s * cfg.nominal_hz {
                    self.locked = true;
                }
            }
            None => {
                self.good_frames = 0;
                self.locked = false;
            }
        }
        out.locked = self.locked;
        out
    }
}

impl Run {
    /// Renders the frames of master chunk `(k, n)` this run covers into `out`. `None`:
    /// the run is closed and has nothing more to give; `Some(None)`: nothing rendered
    /// this time; `Some(Some(r))`: rendered, with the error figures.
    fn render(
        &mut self,
        master: &TimeLine,
        k: u64,
        n: usize,
        cfg: &Config,
        out: &mut FollowerOutput,
        scratch: &mut Vec<Vec<f64>>,
    ) -> Option<Option<Rendered>> {
        let (p0, p1) = positions(master, self, k, n)?;
        let half = (cfg.design.sinc_len / 2) as f64;
        if self.closed && p0 - half - 1.0 > self.received as f64 {
            return None;
        }
        let slope = (p1 - p0) / n as f64;
        let j0 = if self.stage.is_some() { 0 } else { ((half + 1.0 - p0) / slope).ceil().max(0.0) as usize };
        if j0 >= n {
            return Some(None);
        }
        let target = p0 + j0 as f64 * slope;
        if self.stage.is_none() && self.start(target, slope, cfg, scratch).is_err() {
            return Some(None);
        }
        let (stage, origin) = self.stage.as_mut()?;
        let error = target - (*origin as f64 + stage.next_position());
        let corr =
            if cfg.controller { self.ctl.update(error, cfg.control_period_s * cfg.nominal_hz) } else { 1.0 };
        let step = slope * corr;
        stage.set_step(step).ok()?;
        let first = *origin as f64 + stage.next_position();
        self.feed(n - j0, scratch).ok()?;
        let received = self.received as f64;
        for j in 0..n - j0 {
            let pos = first + j as f64 * step;
            if pos + half + 1.0 > received {
                break;
            }
            out.valid[j0 + j] = true;
            for (c, s) in scratch.iter().enumerate() {
                out.samples[(j0 + j) * scratch.len() + c] = crate::sim::to_s32(s[j]);
            }
        }
        let uncertainty = (master.line()?.uncertainty_s + self.line.line()?.uncertainty_s) * cfg.nominal_hz;
        Some(Some(Rendered { error, uncertainty, step }))
    }

    /// Starts the resampler so that its next output frame lies at run position `target`
    /// (see the module doc), stepping `slope` afterwards.
    fn start(
        &mut self,
        target: f64,
        slope: f64,
        cfg: &Config,
        scratch: &mut Vec<Vec<f64>>,
    ) -> Result<(), Error> {
        let mut stage = Stage::new(cfg.design, self.fifo.len(), cfg.max_chunk_frames, 1.0)?;
        let len = cfg.design.sinc_len as f64;
        let origin = (target.floor() - len).max(0.0) as u64;
        // The discarded call of `np` frames at step `sp` moves the next position from
        // `stage.next_position()` (at step `slope`) to `target - origin`.
        stage.set_step(slope)?;
        let rest = target - origin as f64 - stage.next_position();
        let np = (rest.round() as usize).clamp(1, cfg.max_chunk_frames);
        stage.set_step(rest / np as f64)?;
        self.drop_before(origin);
        self.stage = Some((stage, origin));
        self.feed(np, scratch)?;
        if let Some((stage, _)) = self.stage.as_mut() {
            stage.set_step(slope)?;
        }
        Ok(())
    }

    fn drop_before(&mut self, frame: u64) {
        let drop = frame.saturating_sub(self.fifo_start).min(self.fifo.first().map_or(0, |q| q.len() as u64));
        for q in &mut self.fifo {
            q.drain(..drop as usize);
        }
        self.fifo_start += drop;
    }

    /// Runs the resampler for `frames` output frames on the next input frames (zeros past
    /// the delivered ones), into `scratch`.
    fn feed(&mut self, frames: usize, scratch: &mut Vec<Vec<f64>>) -> Result<(), Error> {
        let Some((stage, _)) = self.stage.as_mut() else { return Ok(()) };
        let need = stage.input_needed(frames)?;
        for q in &mut self.fifo {
            if q.len() < need {
                q.resize(need, 0.0);
            }
            q.make_contiguous();
        }
        let inputs: Vec<&[f64]> = self.fifo.iter().map(|q| &q.as_slices().0[..need]).collect();
        scratch.resize(inputs.len(), Vec::new());
        stage.process(&inputs, frames, scratch)?;
        let padded = self.fifo_start + need as u64 > self.received;
        for q in &mut self.fifo {
            q.drain(..need);
        }
        self.fifo_start += need as u64;
        if padded {
            // Zeros were fed: frames delivered later would not be continuous with them.
            self.closed = true;
        }
        Ok(())
    }
}
