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
//! has `a, b` from the lower envelope of `y - c*(x-xc)^2`: the line under every point that
//! minimises the sum of the gaps (a linear programme, solved by the edge of the lower
//! convex hull above the mean `x`). Its slope is the card's rate at the window centre
//! whatever `c` (a chord of a parabola over a symmetric window has the centre's slope), so
//! `c`, a rate slewing linearly, is half the drift of that slope over the recent fits (a
//! least-squares line over the fits of full windows, clamped to ±[`MAX_SLEW_PPM_PER_S`]), once the fits span
//! [`CURVE_MIN_SPAN_S`]; 0 before. Its error shrinks like the delay spread over the number of
//! stamps, against the spread over the square root of it for a least-squares or DLL line,
//! which is what gives sub-microsecond lines from 50–200 µs of wake-up jitter. A smallest
//! delay common to two cards cancels between their lines; a difference between the cards'
//! smallest delays cannot be seen from stamps and is an offset of the alignment.

use std::collections::VecDeque;

/// Window span from which the curvature (slew) is estimated, seconds.
pub const CURVE_MIN_SPAN_S: f64 = 2.0;
/// How many window lengths of slope history the curvature is fitted over.
const SLOPE_HISTORY_WINDOWS: f64 = 3.0;
/// The largest slew the curvature may express, ppm/s (the search range).
pub const MAX_SLEW_PPM_PER_S: f64 = 4.0;
/// A line's uncertainty is this many mean gaps over the number of stamps: a bound that
/// the line's error at the newest frames exceeds in about 0.1 % of chunks, not a typical
/// error. The lower envelope extrapolated from the window's mean to its end errs by about
/// 1.5× the smallest delay of the window's newer half less half that of the older half,
/// an exponential-tailed quantity whose p99.9 is ~20 spreads/n (~40 gaps/n) per card; two
/// cards' errors are independent and partly cancel. Calibrated on the simulator
/// (`examples/honesty.rs`, uniform delays, 20 seeds × +87/+1000 ppm × slew 0/1 ppm/s:
/// 24 gives 0.100 % of locked chunks whose true misalignment exceeds the estimate, and
/// 0.006 % on 20 other seeds at −143/+1000 ppm). Until 2026-12-04 the factor was 4, a
/// typical error: 25–40 % of locked chunks were outside the estimate.
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
    /// Uncertainty of the line, seconds: [`BOUND_GAPS`] mean gaps over the number of
    /// stamps (a p99.9 bound, see there).
    pub uncertainty_s: f64,
}

/// A card's stamps over a window and the line fitted to them.
#[derive(Clone, Debug)]
pub struct TimeLine {
    nominal_hz: f64,
    window_s: f64,
    origin_ns: u64,
    pts: VecDeque<(f64, f64)>,
    /// (window centre, slope there, weight) of the recent fits.
    slopes: VecDeque<(f64, f64, f64)>,
    line: Option<Line>,
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
            slopes: VecDeque::new(),
            line: None,
        }
    }

    /// Stamps in the window.
    pub fn len(&self) -> usize {
        self.pts.len()
    }

    /// No stamp yet.
    pub fn is_empty(&self) -> bool {
        self.pts.is_empty()
    }

    /// Adds the stamp of frame `frame` (the card's frame index) and refits.
    pub fn push(&mut self, frame: f64, stamp_ns: u64) {
        let x = frame / self.nominal_hz;
        let t = (stamp_ns as f64 - self.origin_ns as f64) * 1e-9;
        self.pts.push_back((x, t - x));
        while self.pts.front().is_some_and(|p| x - p.0 > self.window_s) {
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

    fn refit(&mut self) {
        let c = self.curvature();
        let pts = self.pts.make_contiguous();
        let n = pts.len();
        let (x0, x1) = (pts[0].0, pts[n - 1].0);
        let xc = 0.5 * (x0 + x1);
        let xm = pts.iter().map(|p| p.0).sum::<f64>() / n as f64;
        let mut flat = Vec::with_capacity(n);
        let (a, b, gap) = Self::envelope_for(pts, xc, xm, c, &mut flat);
        if x1 - x0 >= 0.95 * self.window_s {
            // Only full windows: the slope of a short one is too noisy to be differentiated.
            self.slopes.push_back((xc, b, 1.0));
            while self.slopes.front().is_some_and(|p| xc - p.0 > SLOPE_HISTORY_WINDOWS * self.window_s) {
                self.slopes.pop_front();
            }
        }
        self.line = Some(Line { a, b, c, xc, uncertainty_s: BOUND_GAPS * gap.max(0.0) / n as f64 });
    }

    /// Half the drift of the slope at the window centre over the recent fits (a
    /// least-squares line through them), once they span [`CURVE_MIN_SPAN_S`].
    fn curvature(&self) -> f64 {
        let (first, last) = match (self.slopes.front(), self.slopes.back()) {
            (Some(f), Some(l)) => (f.0, l.0),
            _ => return 0.0,
        };
        if last - first < CURVE_MIN_SPAN_S {
            return 0.0;
        }
        let w: f64 = self.slopes.iter().map(|p| p.2).sum();
        let xm = self.slopes.iter().map(|p| p.2 * p.0).sum::<f64>() / w;
        let bm = self.slopes.iter().map(|p| p.2 * p.1).sum::<f64>() / w;
        let sxy: f64 = self.slopes.iter().map(|p| p.2 * (p.0 - xm) * (p.1 - bm)).sum();
        let sxx: f64 = self.slopes.iter().map(|p| p.2 * (p.0 - xm) * (p.0 - xm)).sum();
        let max_c = 0.5 * MAX_SLEW_PPM_PER_S * 1e-6;
        (0.5 * sxy / sxx).clamp(-max_c, max_c)
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
}
