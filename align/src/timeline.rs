//! A card's time line: the CLOCK_MONOTONIC instant of each of its frames, estimated from
//! the stamps of its chunks by a lower envelope.
//!
//! A stamp is the true instant of the chunk's first frame plus a wake-up delay that is
//! never negative, so the least-delayed stamps lie on the card's clock (shifted by the
//! smallest delay) and every other stamp lies above it. Over a window of recent stamps
//! (`x` = frame / nominal rate, `y` = stamp − `x`) the line is
//!
//! ```text
//!   y(x) = a + b*(x - xc) + c*(x - xc)^2
//! ```
//!
//! fitted to the points of a long window ([`LONG_WINDOWS`] × `window_s`, 20 s by default):
//! `c` (a rate slewing linearly) is the curvature whose lower envelope has the smallest
//! mean gap — the lower envelope of `y - c*(x-xc)^2` being the line under every point that
//! minimises the sum of the gaps (a linear programme, solved by the edge of the lower
//! convex hull above the mean `x`), and that smallest sum a convex function of `c`
//! (golden-section search, every [`CURVE_SEARCH_EVERY`] refits, once the stamps span
//! [`CURVE_MIN_SPAN_S`]; 0 before); `b` is that envelope's slope; `a` puts the curve under
//! the newest `window_s` of points, touching the lowest. Its error shrinks like the delay
//! spread over the number of stamps, against the spread over the square root of it for a
//! least-squares or DLL line, which is what gives sub-microsecond lines from 50–200 µs of
//! wake-up jitter.
//!
//! Why a long window for the shape and a short one for the offset: the error at the newest
//! frame of a line fitted over one window is about 1.5× the smallest delay of the window's
//! newer half less half that of the older half (the extrapolation from the window's mean to
//! its end); with the slope from a window five times longer it is the smallest delay of the
//! newest window plus a little of the slope's error. In the simulator (`examples/honesty.rs`,
//! 20 seeds, 1 ppm/s): one window with the curvature from its slopes' drift (until
//! 2026-12-04) 0.100 sample RMS aligned after lock; this, 0.079, and 0.043 once the long
//! window is full. The curvature must come from the long window itself: from the slopes'
//! drift it was not good enough to carry 12 s at 1 ppm/s (RMS 0.143).
//!
//! A smallest delay common to two cards cancels between their lines; a difference between
//! the cards' smallest delays cannot be seen from stamps and is an offset of the alignment.

use std::collections::VecDeque;

/// The long window the curvature and slope are fitted over, in windows.
pub const LONG_WINDOWS: f64 = 5.0;
/// The curvature is searched once the stamps span this, seconds (0 before).
pub const CURVE_MIN_SPAN_S: f64 = 6.0;
/// The curvature is searched every this many refits (a slew moves it slowly); the line
/// under it is refitted with every new group of stamps ([`GROUP_S`]).
const CURVE_SEARCH_EVERY: u64 = 10;
/// Stamps within this span of frames (seconds) are one group, of which the lowest is kept
/// (10 ms: every stamp of a 480-frame chunk at 48 kHz is its own group).
pub const GROUP_S: f64 = 0.0099;
/// Golden-section steps of the curvature search (the range shrinks 0.618× per step).
const CURVE_SEARCH_STEPS: usize = 48;
/// The largest slew the curvature may express, ppm/s (the search range).
pub const MAX_SLEW_PPM_PER_S: f64 = 4.0;
/// A line's uncertainty is this many mean gaps of the newest window's stamps over their
/// number: a bound that the line's error at the newest frames exceeds in about 0.1 % of
/// chunks, not a typical error (the error is exponential-tailed: the smallest of the
/// newest stamps' delays, plus the shape's error; two cards' errors are independent and
/// partly cancel). Calibrated on the simulator (`examples/honesty.rs`, uniform 50–200 µs
/// delays; true misalignment against the estimate of every locked chunk): 0.025 % over it on
/// 80 runs (seeds 1–20 × +87/+1000 ppm × slew 0/1 ppm/s), 0.069 % on 120 others (seeds
/// 21–40 × −143/+1000 ppm × slew 0/0.5/1; 18 gave 0.48 % there, 28 no lock in 4 runs).
/// Until 2026-12-04 the factor was 4, a typical error: 25–40 % of locked chunks were
/// outside the estimate.
pub const BOUND_GAPS: f64 = 24.0;

/// The lower-envelope line through points sorted by `x`, taken at `at`: `(value at
/// `at`, slope)`, or `None` without points.
fn envelope_at(pts: &[(f64, f64)], at: f64) -> Option<(f64, f64)> {
    let mut hull: Vec<(f64, f64)> = Vec::with_capacity(32);
    for &p in pts {
        while hull.len() >= 2 {
            let (o, a) = (hull[hull.len() - 2], hull[hull.len() - 1]);
            // Drop `a` unless o -> a -> p turns left (a stays below the chord o-p).
            if (a.0 - o.0) * (p.1 - o.1) - (a.1 - o.1) * (p.0 - o.0) <= 0.0 {
                hull.pop();
            } else {
                break;
            }
        }
        hull.push(p);
    }
    if hull.len() == 1 {
        return Some((hull[0].1, 0.0));
    }
    let i = hull.windows(2).position(|w| w[1].0 >= at).unwrap_or(hull.len() - 2);
    let (p, q) = (hull.get(i)?, hull.get(i + 1)?);
    let slope = (q.1 - p.1) / (q.0 - p.0);
    Some((p.1 + slope * (at - p.0), slope))
}

/// The fitted line of one card.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Line {
    /// `y` at `xc`, seconds.
    pub a: f64,
    /// Rate offset (dimensionless, 1e-6 = 1 ppm slow).
    pub b: f64,
    /// Curvature, 1/s.
    pub c: f64,
    /// Centre of the window, seconds of nominal frames.
    pub xc: f64,
    /// Uncertainty of the line, seconds: [`BOUND_GAPS`] mean gaps of the newest window's
    /// points over their number (a p99.9 bound, see there).
    pub uncertainty_s: f64,
}

/// A card's stamps over a window and the line fitted to them.
#[derive(Clone, Debug)]
pub struct TimeLine {
    nominal_hz: f64,
    window_s: f64,
    origin_ns: u64,
    pts: VecDeque<(f64, f64)>,
    line: Option<Line>,
    /// The last searched curvature, and refits since the search began.
    curve: Option<f64>,
    refits: u64,
    /// `x` of the first stamp of the newest group.
    group_x: f64,
}

impl TimeLine {
    /// A line for a card of nominal rate `nominal_hz`, fitted over the last `window_s` of
    /// stamps, with times measured from `origin_ns` (a CLOCK_MONOTONIC instant shared by
    /// the cards that are aligned).
    pub fn new(nominal_hz: f64, window_s: f64, origin_ns: u64) -> TimeLine {
        TimeLine {
            nominal_hz,
            window_s,
            origin_ns,
            pts: VecDeque::new(),
            line: None,
            curve: None,
            refits: 0,
            group_x: f64::NEG_INFINITY,
        }
    }

    /// Points in the window (one per group of stamps, see [`TimeLine::push`]).
    pub fn len(&self) -> usize {
        self.pts.len()
    }

    /// No stamp yet.
    pub fn is_empty(&self) -> bool {
        self.pts.is_empty()
    }

    /// Adds the stamp of frame `frame` (the card's frame index) and refits. Stamps less than
    /// [`GROUP_S`] of frames after the first of their group are a group: only its lowest
    /// stamp (against the current slope) is kept, and the line is refitted when a group
    /// begins — so that short chunks (64 frames: 750 stamps a second) cost no more than
    /// 10 ms ones, and the long window holds at most 2000 points.
    pub fn push(&mut self, frame: f64, stamp_ns: u64) {
        let x = frame / self.nominal_hz;
        let t = (stamp_ns as f64 - self.origin_ns as f64) * 1e-9;
        let y = t - x;
        if let (Some(last), Some(line)) = (self.pts.back_mut(), self.line) {
            if x - self.group_x < GROUP_S {
                if y - line.b * x < last.1 - line.b * last.0 {
                    *last = (x, y);
                }
                return;
            }
        }
        self.group_x = x;
        self.pts.push_back((x, y));
        while self.pts.front().is_some_and(|p| x - p.0 > LONG_WINDOWS * self.window_s) {
            self.pts.pop_front();
        }
        self.refit();
    }

    /// The lower-envelope line of the points less `c*(x-xc)^2`: `(a, b, mean gap)`.
    fn envelope_for(
        pts: &[(f64, f64)],
        xc: f64,
        xm: f64,
        c: f64,
        flat: &mut Vec<(f64, f64)>,
    ) -> (f64, f64, f64) {
        flat.clear();
        flat.extend(pts.iter().map(|&(x, y)| (x, y - c * (x - xc) * (x - xc))));
        let (ym, b) = envelope_at(flat, xm).unwrap_or((0.0, 0.0));
        let mean = flat.iter().map(|p| p.1).sum::<f64>() / flat.len() as f64;
        (ym + b * (xc - xm), b, mean - ym)
    }

    /// The quadratic lower envelope over the long window: the curvature `c` minimising the
    /// mean gap (a convex function of `c`: golden-section search), the line under the
    /// flattened points at their mean, and the offset from the newest `window_s` of points.
    fn refit(&mut self) {
        let pts = self.pts.make_contiguous();
        let n = pts.len();
        let (x0, x1) = (pts[0].0, pts[n - 1].0);
        let xc = 0.5 * (x0 + x1);
        let xm = pts.iter().map(|p| p.0).sum::<f64>() / n as f64;
        let mut flat = Vec::with_capacity(n);
        let c = if x1 - x0 < CURVE_MIN_SPAN_S {
            0.0
        } else if let (Some(c), false) = (self.curve, self.refits % CURVE_SEARCH_EVERY == 0) {
            c
        } else {
            let max_c = 0.5 * MAX_SLEW_PPM_PER_S * 1e-6;
            let mut gap = |c: f64| Self::envelope_for(pts, xc, xm, c, &mut flat).2;
            let (mut lo, mut hi) = (-max_c, max_c);
            let r = 0.5 * (5f64.sqrt() - 1.0);
            let (mut m1, mut m2) = (hi - r * (hi - lo), lo + r * (hi - lo));
            let (mut g1, mut g2) = (gap(m1), gap(m2));
            for _ in 0..CURVE_SEARCH_STEPS {
                if g1 <= g2 {
                    hi = m2;
                    (m2, g2) = (m1, g1);
                    m1 = hi - r * (hi - lo);
                    g1 = gap(m1);
                } else {
                    lo = m1;
                    (m1, g1) = (m2, g2);
                    m2 = lo + r * (hi - lo);
                    g2 = gap(m2);
                }
            }
            0.5 * (lo + hi)
        };
        if x1 - x0 >= CURVE_MIN_SPAN_S {
            self.curve = Some(c);
            self.refits += 1;
        }
        let (_, b, _) = Self::envelope_for(pts, xc, xm, c, &mut flat);
        // The offset: the lowest of the newest window's points under the long window's shape,
        // and their mean gap above it.
        let from = x1 - self.window_s;
        let rest = |&(x, y): &(f64, f64)| y - b * (x - xc) - c * (x - xc) * (x - xc);
        let recent = || pts.iter().filter(|p| p.0 >= from).map(rest);
        let a = recent().fold(f64::INFINITY, f64::min);
        let (sum, m) = recent().fold((0.0, 0usize), |(s, m), r| (s + r - a, m + 1));
        let gap = sum / m as f64;
        self.line = Some(Line { a, b, c, xc, uncertainty_s: BOUND_GAPS * gap.max(0.0) / m as f64 });
    }

    /// The fitted line, once a stamp was pushed.
    pub fn line(&self) -> Option<Line> {
        self.line
    }

    /// The instant of (fractional) frame `frame`, seconds from the origin.
    pub fn time_of(&self, frame: f64) -> Option<f64> {
        let l = self.line?;
        let x = frame / self.nominal_hz;
        let d = x - l.xc;
        Some(x + l.a + l.b * d + l.c * d * d)
    }

    /// The (fractional) frame at `t`, seconds from the origin (the inverse of
    /// [`TimeLine::time_of`], by Newton steps).
    pub fn frame_at(&self, t: f64) -> Option<f64> {
        let l = self.line?;
        let mut x = (t - l.a + l.b * l.xc) / (1.0 + l.b);
        for _ in 0..3 {
            let d = x - l.xc;
            let f = x + l.a + l.b * d + l.c * d * d - t;
            x -= f / (1.0 + l.b + 2.0 * l.c * d);
        }
        Some(x * self.nominal_hz)
    }

    /// The rate the line gives at (fractional) frame `frame`, Hz.
    pub fn rate_at(&self, frame: f64) -> Option<f64> {
        let l = self.line?;
        let d = frame / self.nominal_hz - l.xc;
        Some(self.nominal_hz / (1.0 + l.b + 2.0 * l.c * d))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::Rng;

    /// A card 87 ppm fast and slewing 1 ppm/s, stamps delayed by 50..200 µs, a 4 s
    /// window: from 6 s on the line puts the newest frame within 8 µs of its true instant
    /// (typically 1–2 µs; the spikes are the hull's, see the module doc).
    #[test]
    fn the_lower_envelope_finds_the_clock_through_wake_up_jitter() {
        let clock = crate::sim::Clock { nominal_hz: 48_000.0, ppm: 87.0, slew_ppm_per_s: 1.0, start_s: 0.0 };
        let mut line = TimeLine::new(48_000.0, 4.0, 0);
        let mut rng = Rng::new(5);
        let mut worst = 0.0f64;
        for k in 0..1200u64 {
            let frame = (k * 480) as f64;
            let t = clock.instant(frame) + 50e-6 + rng.next_f64() * 150e-6;
            line.push(frame, (t * 1e9) as u64);
            if k > 600 {
                let err = line.time_of(frame).unwrap() - clock.instant(frame) - 50e-6;
                worst = worst.max(err.abs());
            }
        }
        assert!(worst < 8e-6, "the line was {:.2} µs off", worst * 1e6);
    }

    /// The long window's shape: over 20 seeds of a card 87 ppm fast slewing 1 ppm/s
    /// (50–200 µs delays), once the 20 s window is full, the line's error at the newest
    /// frame is under 1 µs RMS (0.64 µs measured; one 4 s window with the curvature from its
    /// slopes' drift, before 2026-12-04: 1.51 µs).
    #[test]
    fn the_long_window_puts_the_newest_frame_within_a_microsecond() {
        let clock = crate::sim::Clock { nominal_hz: 48_000.0, ppm: 87.0, slew_ppm_per_s: 1.0, start_s: 0.0 };
        let (mut sum, mut n) = (0.0, 0);
        for seed in 1..=20 {
            let mut line = TimeLine::new(48_000.0, 4.0, 0);
            let mut rng = Rng::new(seed);
            for k in 0..3000u64 {
                let frame = (k * 480) as f64;
                let t = clock.instant(frame) + 50e-6 + rng.next_f64() * 150e-6;
                line.push(frame, (t * 1e9) as u64);
                if k >= 2100 {
                    let err = line.time_of(frame).unwrap() - clock.instant(frame) - 50e-6;
                    sum += err * err;
                    n += 1;
                }
            }
        }
        let rms = (sum / n as f64).sqrt();
        assert!(rms < 1e-6, "the newest frame was {:.3} µs RMS off", rms * 1e6);
    }

    /// 64-frame chunks (750 stamps a second): the long window holds one point per 10 ms
    /// group (at most 2000), and the newest frame is as close to its instant as with
    /// 480-frame chunks (under 1 µs RMS once the window is full; the lowest of a group's
    /// ~7.5 stamps is a better point than one stamp).
    #[test]
    fn short_chunks_are_grouped_and_lose_nothing() {
        let clock =
            crate::sim::Clock { nominal_hz: 48_000.0, ppm: -143.0, slew_ppm_per_s: 0.5, start_s: 0.0 };
        let (mut sum, mut n) = (0.0, 0);
        for seed in 1..=4 {
            let mut line = TimeLine::new(48_000.0, 4.0, 0);
            let mut rng = Rng::new(seed);
            for k in 0..22_500u64 {
                let frame = (k * 64) as f64;
                let t = clock.instant(frame) + 50e-6 + rng.next_f64() * 150e-6;
                line.push(frame, (t * 1e9) as u64);
                assert!(line.len() <= 2001, "{} points in the window", line.len());
                if k >= 15_750 && k % 8 == 0 {
                    let err = line.time_of(frame).unwrap() - clock.instant(frame) - 50e-6;
                    sum += err * err;
                    n += 1;
                }
            }
        }
        let rms = (sum / n as f64).sqrt();
        assert!(rms < 1e-6, "the newest frame was {:.3} µs RMS off", rms * 1e6);
    }
}
