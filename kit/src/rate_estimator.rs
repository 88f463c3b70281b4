//! The device-clock rate estimator: a second-order delay-locked loop (DLL) over
//! (frames, CLOCK_MONOTONIC) pairs, after F. Adriaensen, "Using a DLL to filter time"
//! (2005), the loop JACK and PipeWire use for the same purpose, behind a stamp-quality
//! filter.
//!
//! Every `period` frames the device delivers a chunk, observed at time `t`; the loop
//! predicts `t1`, the time of the next chunk, and `e2`, the period duration, and corrects
//! both with the prediction error `e = t - t1`:
//!
//! ```text
//!   t1 <- t1 + b*e + e2        b = sqrt(2)*w,  c = w^2,  w = 2*pi*B*e2
//!   e2 <- e2 + c*e             rate = period / e2
//! ```
//!
//! B is the loop bandwidth in Hz. It starts wide (fast lock) and narrows as the loop runs
//! (1 Hz for the first second of device time, 0.25 Hz up to 4 s, then 0.05 Hz), and `w` is
//! capped at 0.5 so that very long periods stay stable.
//!
//! **Stamp quality.** An observed time is the capture time plus a delay that is never
//! negative: the wake-up latency of the thread that saw the chunk. On a loaded machine
//! the delay comes in bursts (a starved thread, then a catch-up of several chunks at once),
//! and a loop fed those stamps follows the bursts instead of the device. So, as the seed's
//! PipeWire decode buffer does with its buffer level ("the spike is the long-window
//! maximum ..."), the filter keeps the *minimum* prediction error over a window (1 s of
//! device time, in four sub-windows that age out one at a time): the stamps of least
//! delay, the best view of the device clock. Their minima, carried forward along the line
//! through the oldest and newest of them (so that a loop whose rate is still off keeps
//! finding them), are the reference; a stamp later than the reference by more than a
//! tolerance (250 µs, or an eighth of a period if longer) does not correct the loop, which
//! then runs free for that period (`t1 <- t1 + e2`). A stamp more than 8 periods late (a
//! stall and its catch-up) is not even counted in the window.
//! There is no anchor reset for late stamps: after a stall the loop's prediction is still
//! where the device is, and the first on-time stamp is accepted again. The anchor itself
//! (the first stamp, or the first after a gap) may be late: for 0.1 s (at least 4
//! periods) after it, the anchor only moves to earlier stamps and the period is left alone.
//!
//! As a last resort against a lock-out, a stamp within 4 tolerances of the reference is
//! accepted when none was accepted for a whole window. [`RateDll::skip`] advances the
//! loop by one period without a stamp (a chunk whose stamp is known to be late);
//! [`RateDll::reset`] forgets the anchor after a gap in the frames (an overrun).

use std::f64::consts::{PI, SQRT_2};

/// Device time covered by the minimum-delay window, in seconds.
const WINDOW_S: f64 = 1.0;
/// Sub-windows of the window (each ages out as a whole, as in PipeWire's windowed min/max).
const BUCKETS: usize = 4;
/// Device time after an anchor during which the anchor only moves to earlier stamps.
const SETTLE_S: f64 = 0.1;
/// Stamps later than the predicted time by more than this many periods are outliers.
const OUTLIER_PERIODS: f64 = 8.0;

/// The least-delayed stamps over a window of device time, in [`BUCKETS`] sub-windows that
/// age out one at a time: each keeps its minimum prediction error and when it was seen.
#[derive(Clone, Debug)]
struct WindowMin {
    /// (minimum error, device time of it) per sub-window, oldest first.
    mins: [(f64, f64); BUCKETS],
    /// Device time at which the newest sub-window began.
    start: f64,
    /// Device time at which the window began to fill (it holds a whole window from
    /// `born + WINDOW_S` on).
    born: f64,
}

/// The largest drift of the reference line the filter follows (5000 ppm).
const MAX_SLOPE: f64 = 5e-3;

impl WindowMin {
    fn new(now: f64) -> WindowMin {
        WindowMin { mins: [(f64::INFINITY, now); BUCKETS], start: now, born: now }
    }

    /// Adds error `v` seen at device time `now`.
    fn push(&mut self, v: f64, now: f64) {
        let span = WINDOW_S / BUCKETS as f64;
        if now - self.start >= WINDOW_S {
            *self = WindowMin::new(now);
        }
        while now - self.start >= span {
            self.mins.rotate_left(1);
            self.start += span;
            self.mins[BUCKETS - 1] = (f64::INFINITY, self.start);
        }
        let last = &mut self.mins[BUCKETS - 1];
        if v < last.0 {
            *last = (v, now);
        }
    }

    /// The lowest of the sub-window minima carried to `now` along `slope`, and how far apart
    /// they lie (the line's own uncertainty; 0 with fewer than two).
    fn envelope(&self, now: f64, slope: f64) -> Option<(f64, f64)> {
        let carried = self.mins.iter().filter(|(v, _)| v.is_finite()).map(|&(v, at)| v + slope * (now - at));
        let (lo, hi) = carried.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
        (hi >= lo).then_some((lo, hi - lo))
    }

    /// The minimum-delay reference at device time `now`: the lowest of the sub-window
    /// minima, each carried forward along the line through the oldest and newest of them.
    /// The line's slope is the loop's own rate error as the least-delayed stamps see it, so
    /// a loop that is off still finds stamps near the reference (no lock-out).
    fn reference(&self, now: f64) -> Option<f64> {
        self.carried(now).reduce(f64::min)
    }

    /// The sub-window minima, each carried forward to `now` along the line through the
    /// oldest and newest of them.
    fn carried(&self, now: f64) -> impl Iterator<Item = f64> + '_ {
        let mut filled = self.mins.iter().filter(|(v, _)| v.is_finite());
        let first = filled.next().copied();
        let last = filled.next_back().copied().or(first);
        let slope = match (first, last) {
            (Some(f), Some(l)) if l.1 - f.1 >= WINDOW_S / BUCKETS as f64 => {
                ((l.0 - f.0) / (l.1 - f.1)).clamp(-MAX_SLOPE, MAX_SLOPE)
            }
            _ => 0.0,
        };
        self.mins.iter().filter(|(v, _)| v.is_finite()).map(move |&(v, at)| v + slope * (now - at))
    }
}

/// The lower envelope of the stamps in absolute terms: each stamp's distance from the
/// nominal-rate line through the anchor, its minima over a window ([`WindowMin`], whose
/// carried slope takes up the device's rate error). Unlike the loop's prediction it has no
/// moving baseline, so it is where the least-delayed stamps lie ([`RateDll::stamp_bound_ns`]).
#[derive(Clone, Debug)]
struct Floor {
    /// The anchor stamp (s after the origin).
    from: f64,
    /// Periods since the anchor of the last stamp (or skipped period).
    k: u64,
    /// Nominal period (s).
    period: f64,
    win: WindowMin,
}

impl Floor {
    fn new(from: f64, period: f64) -> Floor {
        let mut f = Floor { from, k: 0, period, win: WindowMin::new(0.0) };
        f.win.push(0.0, 0.0);
        f
    }

    /// Distance of a stamp `t`, `k` periods after the anchor, from the nominal line, and the
    /// window key of it.
    fn residual(&self, t: f64, k: u64) -> (f64, f64) {
        let at = k as f64 * self.period;
        (t - (self.from + at), at)
    }

    fn push(&mut self, t: f64) {
        let (r, at) = self.residual(t, self.k);
        self.win.push(r, at);
    }

    /// The bound of stamp `t` of the next period, once the window has filled; `slope` is the
    /// device's rate error against nominal (the loop's estimate), along which the minima are
    /// carried (their own first-to-last slope is too noisy over one window for this).
    fn bound(&self, t: f64, slope: f64) -> Option<f64> {
        let (r, at) = self.residual(t, self.k + 1);
        if at - self.win.born < WINDOW_S {
            return None;
        }
        let (line, spread) = self.win.envelope(at, slope)?;
        Some((r - line).abs() + spread)
    }
}

/// The DLL state.
#[derive(Clone, Debug)]
pub struct RateDll {
    period_frames: f64,
    nominal_hz: f64,
    origin_ns: Option<u64>,
    t1: f64,
    e2: f64,
    anchored: bool,
    elapsed: f64,
    window: WindowMin,
    /// Device time since a stamp last corrected the loop.
    since_accepted: f64,
    /// Device time of consecutive outliers (a safety net re-anchors after 10 s of them).
    outliers_for: f64,
    /// Device time until which the anchor settles (see [`RateDll::update`]).
    settle_until: f64,
    /// Where the least-delayed stamps lie (None before the first anchor).
    floor: Option<Floor>,
}

impl RateDll {
    /// A loop for a device of nominal rate `nominal_hz` delivering `period_frames` per update.
    pub fn new(nominal_hz: f64, period_frames: u32) -> RateDll {
        let period_frames = f64::from(period_frames.max(1));
        RateDll {
            period_frames,
            origin_ns: None,
            t1: 0.0,
            e2: period_frames / nominal_hz.max(1.0),
            nominal_hz: nominal_hz.max(1.0),
            anchored: false,
            elapsed: 0.0,
            window: WindowMin::new(0.0),
            since_accepted: 0.0,
            outliers_for: 0.0,
            settle_until: 0.0,
            floor: None,
        }
    }

    /// Forgets the time anchor (after a gap in the frames); the period estimate is kept.
    pub fn reset(&mut self) {
        self.anchored = false;
        self.floor = None;
        self.window = WindowMin::new(self.elapsed);
        self.since_accepted = 0.0;
        self.outliers_for = 0.0;
    }

    /// Advances the loop by one period whose stamp is not to be used (flagged late).
    pub fn skip(&mut self) {
        if self.anchored {
            self.free_run();
            if let Some(f) = self.floor.as_mut() {
                f.k += 1;
            }
        }
    }

    fn free_run(&mut self) {
        self.t1 += self.e2;
        self.elapsed += self.e2;
        self.since_accepted += self.e2;
    }

    fn bandwidth(&self) -> f64 {
        if self.elapsed < 1.0 {
            1.0
        } else if self.elapsed < 4.0 {
            0.25
        } else {
            0.05
        }
    }

    /// How far above the window's minimum a stamp may lie and still correct the loop.
    fn tolerance(&self) -> f64 {
        (self.e2 / 8.0).max(250e-6)
    }

    fn anchor(&mut self, t: f64) {
        self.floor = Some(Floor::new(t, self.period_frames / self.nominal_hz));
        self.t1 = t + self.e2;
        self.anchored = true;
        self.window = WindowMin::new(self.elapsed);
        self.since_accepted = 0.0;
        self.outliers_for = 0.0;
        self.settle_until = self.elapsed + SETTLE_S.max(4.0 * self.e2);
    }

    /// Feeds the time (CLOCK_MONOTONIC ns) at which the next period arrived; returns the
    /// rate estimate in Hz.
    pub fn update(&mut self, t_ns: u64) -> f64 {
        let origin = *self.origin_ns.get_or_insert(t_ns);
        let t = (t_ns as f64 - origin as f64) * 1e-9;
        if !self.anchored {
            self.anchor(t);
            return self.rate();
        }
        let e = t - self.t1;
        if let Some(f) = self.floor.as_mut() {
            f.k += 1;
            if e <= OUTLIER_PERIODS * self.e2 {
                f.push(t);
            }
        }
        if self.elapsed < self.settle_until {
            // The first stamp may itself be late: for a few periods the anchor only moves to
            // earlier stamps (delays are never negative) and the period is left alone.
            self.t1 += e.min(0.0);
            self.free_run();
            return self.rate();
        }
        if e < -OUTLIER_PERIODS * self.e2 {
            // Far earlier than predicted: the clock stepped back (or the anchor was late).
            self.anchor(t);
            return self.rate();
        }
        if e > OUTLIER_PERIODS * self.e2 {
            // A stall's catch-up: no information about the device clock.
            self.outliers_for += self.e2;
            if self.outliers_for > 10.0 {
                self.anchor(t);
            } else {
                self.free_run();
            }
            return self.rate();
        }
        self.outliers_for = 0.0;
        self.window.push(e, self.elapsed);
        let above = e - self.window.reference(self.elapsed).unwrap_or(e);
        let tol = self.tolerance();
        let good = above <= tol || (self.since_accepted >= WINDOW_S && above <= 4.0 * tol);
        if !good {
            self.free_run();
            return self.rate();
        }
        let w = (2.0 * PI * self.bandwidth() * self.e2).min(0.5);
        self.t1 += SQRT_2 * w * e + self.e2;
        self.e2 += w * w * e;
        self.elapsed += self.e2;
        self.since_accepted = 0.0;
        self.rate()
    }

    /// The current estimate in Hz.
    pub fn rate(&self) -> f64 {
        self.period_frames / self.e2
    }

    /// A bound (ns) of how far a chunk stamped `t_ns` lies from its true capture instant,
    /// asked before the chunk's own [`RateDll::update`]. A stamp is the instant plus a delay
    /// that is never negative; the least-delayed stamps of the window lie on a line (the
    /// filter's reference, carried to this chunk), so the instant lies within the stamp's
    /// distance from that line, widened by how much the window's minima disagree (the line's
    /// own uncertainty) and by one frame (no stamp is finer than a sample). None while the
    /// loop has no settled line (until its window has filled, 1 s of device time after the
    /// first stamp or after [`RateDll::reset`]): the caller
    /// gives its a-priori bound then. What the line cannot see is a delay every stamp shares
    /// (the converter's constant latency): docs/time.md says so.
    pub fn stamp_bound_ns(&self, t_ns: u64) -> Option<u64> {
        let origin = self.origin_ns?;
        if !self.anchored {
            return None;
        }
        let t = (t_ns as f64 - origin as f64) * 1e-9;
        // The device's period is e2 where the nominal line assumes period_frames / nominal.
        let slope = self.e2 * self.nominal_hz / self.period_frames - 1.0;
        let b = self.floor.as_ref()?.bound(t, slope)? + 1.0 / self.nominal_hz;
        b.is_finite().then(|| (b * 1e9).ceil() as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic pseudo-random numbers in [0, 1) (a 64-bit LCG).
    struct Lcg(u64);

    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn ppm(rate: f64, true_rate: f64) -> f64 {
        (rate / true_rate - 1.0) * 1e6
    }

    /// A device 100 ppm fast, observed with ±200 µs of deterministic pseudo-random jitter.
    #[test]
    fn the_loop_finds_a_device_running_100_ppm_fast_through_jitter() {
        let (nominal, period) = (48_000.0, 480u32);
        let true_rate = nominal * (1.0 + 100e-6);
        let mut dll = RateDll::new(nominal, period);
        let mut rng = Lcg(12345);
        let mut rate = 0.0;
        for k in 0..3000u64 {
            let jitter = (rng.next() - 0.5) * 400e-6;
            let t = 1.0 + k as f64 * f64::from(period) / true_rate + jitter;
            rate = dll.update((t * 1e9) as u64);
        }
        let p = ppm(rate, true_rate);
        assert!(p.abs() < 5.0, "estimate {rate} Hz is {p} ppm off {true_rate} Hz");
    }

    /// The stamp bound against the truth: a device 100 ppm fast, stamps late by 0–300 µs
    /// (a thread's wake-up delay, never early), bursts of 2 ms late every 97th chunk. Every
    /// settled bound must hold the stamp's distance from the true instant, and stay narrow.
    #[test]
    fn the_stamp_bound_holds_the_truth_through_jitter_and_bursts() {
        let (nominal, period) = (48_000.0, 480u32);
        let true_rate = nominal * (1.0 + 100e-6);
        let mut dll = RateDll::new(nominal, period);
        let mut rng = Lcg(777);
        let (mut bounded, mut widths) = (0, Vec::new());
        for k in 0..6000u64 {
            let truth = 1.0 + k as f64 * f64::from(period) / true_rate;
            let delay = if k % 97 == 50 { 2e-3 } else { rng.next() * 300e-6 };
            let t = ((truth + delay) * 1e9) as u64;
            if let Some(b) = dll.stamp_bound_ns(t) {
                let err = (t as f64 - truth * 1e9).abs();
                assert!(err <= b as f64 + 1.0, "chunk {k}: stamp {err} ns from the truth, bound {b} ns");
                bounded += 1;
                widths.push(b);
            }
            dll.update(t);
        }
        assert!(bounded > 5850, "only {bounded} of 6000 chunks had a settled bound");
        widths.sort_unstable();
        let median = widths[widths.len() / 2];
        // The delays are 0–300 µs (median 150): the bound adds the line's width and one frame.
        assert!(median < 250_000, "median bound {median} ns: wider than the delays warrant");
    }

    #[test]
    fn a_reset_keeps_the_period_estimate() {
        let mut dll = RateDll::new(44_100.0, 2205);
        for k in 0..100u64 {
            dll.update(k * 50_000_000);
        }
        let before = dll.rate();
        dll.reset();
        assert_eq!(dll.update(10_000_000_000), before);
    }

    /// The stamps a starved capture thread produces, in simulated time: device chunk `k` is
    /// due at `k * period / rate`; the thread sees it at `max(due, busy_until) + latency`,
    /// where `busy_until` is when the thread gets the CPU back. Returns the estimate after
    /// every chunk, with the chunk's due time.
    struct Starved {
        rate: f64,
        period: u32,
        rng: Lcg,
        busy_until: f64,
    }

    impl Starved {
        fn stamp(&mut self, k: u64) -> (f64, f64) {
            let due = 0.5 + k as f64 * f64::from(self.period) / self.rate;
            // Wake-up latency: 20..120 µs usually; every ~50 ms of device time the thread
            // loses the CPU for 1..15 ms (four busy loops on two cores, no RT priority).
            let latency = 20e-6 + self.rng.next() * 100e-6;
            if self.rng.next() < f64::from(self.period) / self.rate / 0.05 {
                self.busy_until = due + 1e-3 + self.rng.next() * 14e-3;
            }
            // Chunks that came due while the thread was off the CPU are seen together.
            (due, due.max(self.busy_until) + latency)
        }
    }

    /// 48 kHz exactly, 32-frame chunks, jitter bursts throughout (the first
    /// stamps 4 ms late), a 2 s stall at 20 s. After the lock (5 s of device time) the
    /// estimate stays within ±20 ppm, and within
    /// 2 s of the stall's end it is within ±20 ppm again (it never leaves). Simulated time:
    /// deterministic.
    #[test]
    fn late_stamp_bursts_and_a_2_s_stall_keep_the_estimate_within_20_ppm() {
        let (rate, period) = (48_000.0, 32u32);
        let mut dll = RateDll::new(rate, period);
        let mut dev = Starved { rate, period, rng: Lcg(7), busy_until: 0.5 + 4e-3 };
        let (stall_at, stall_s) = (20.0, 2.0);
        let mut worst = 0.0f64;
        let mut worst_after_stall = 0.0f64;
        let chunks = (40.0 * rate / f64::from(period)) as u64;
        for k in 0..chunks {
            let (due, mut seen) = dev.stamp(k);
            if due >= stall_at && due < stall_at + stall_s {
                // SIGSTOP: nothing is seen until the stall ends, then the backlog at once.
                seen = seen.max(stall_at + stall_s + 1e-4);
            }
            let p = ppm(dll.update((seen * 1e9) as u64), rate);
            if due > 5.0 {
                worst = worst.max(p.abs());
            }
            if due > stall_at + stall_s + 2.0 {
                worst_after_stall = worst_after_stall.max(p.abs());
            }
        }
        assert!(worst <= 20.0, "the estimate went {worst:.1} ppm off under late-stamp bursts and a stall");
        assert!(worst_after_stall <= 20.0, "{worst_after_stall:.1} ppm off 2 s after the stall");
    }

    /// The same device 300 ppm slow, so the filter must not stop a real offset from being
    /// learnt: the loop converges through the bursts.
    #[test]
    fn a_device_300_ppm_slow_is_found_through_late_stamp_bursts() {
        let (nominal, period) = (48_000.0, 32u32);
        let true_rate = nominal * (1.0 - 300e-6);
        let mut dll = RateDll::new(nominal, period);
        let mut dev = Starved { rate: true_rate, period, rng: Lcg(99), busy_until: 0.5 + 4e-3 };
        let mut worst = 0.0f64;
        for k in 0..(30.0 * true_rate / f64::from(period)) as u64 {
            let (due, seen) = dev.stamp(k);
            let p = ppm(dll.update((seen * 1e9) as u64), true_rate);
            if due > 8.0 {
                worst = worst.max(p.abs());
            }
        }
        assert!(worst <= 20.0, "{worst:.1} ppm off a device 300 ppm slow");
    }

    /// A nominal rate 3000 ppm off the device's (a loop far off when the filter starts):
    /// the reference line follows the drift, so the loop is not locked out.
    #[test]
    fn a_device_3000_ppm_off_its_nominal_rate_is_found_through_late_stamp_bursts() {
        for (seed, off) in [(3u64, 3000e-6), (4, -3000e-6)] {
            let (nominal, period) = (48_000.0, 32u32);
            let true_rate = nominal * (1.0 + off);
            let mut dll = RateDll::new(nominal, period);
            let mut dev = Starved { rate: true_rate, period, rng: Lcg(seed), busy_until: 0.5 + 4e-3 };
            let mut worst = 0.0f64;
            for k in 0..(30.0 * true_rate / f64::from(period)) as u64 {
                let (due, seen) = dev.stamp(k);
                let p = ppm(dll.update((seen * 1e9) as u64), true_rate);
                if due > 8.0 {
                    worst = worst.max(p.abs());
                }
            }
            assert!(worst <= 20.0, "{worst:.1} ppm off a device {:.0} ppm off nominal", off * 1e6);
        }
    }

    /// Chunks skipped as flagged late keep the loop where the device is.
    #[test]
    fn skipped_periods_keep_the_prediction_on_the_device_clock() {
        let (rate, period) = (48_000.0, 480u32);
        let mut dll = RateDll::new(rate, period);
        let at = |k: u64| ((1.0 + k as f64 * f64::from(period) / rate) * 1e9) as u64;
        for k in 0..1000 {
            dll.update(at(k));
        }
        for _ in 1000..1200 {
            dll.skip();
        }
        for k in 1200..1300 {
            let p = ppm(dll.update(at(k)), rate);
            assert!(p.abs() < 1.0, "{p} ppm after skipped periods");
        }
    }
}
