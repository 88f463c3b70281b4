//! The rate controller: a proportional correction of the feed-forward step on the
//! follower's position error.
//!
//! `error` is the target follower position (from the two time lines) minus the resampler's
//! (frames). The step the time lines give (the feed-forward, `(p(k+n) - p(k))/n`) already
//! carries the rate, so the controller only has to remove a position error: each chunk it
//! returns
//!
//! ```text
//!   corr = 1 + error / period
//! ```
//!
//! (`period` in frames), which multiplies the feed-forward step; the error then decays as
//! `exp(-t/period)` without overshoot, and a step error `d` of the feed-forward leaves a
//! position error of only `d * period`, which goes when the line's slope improves.
//!
//! Measured why not the seed's decode-buffer controller (PipeWire bluez5, an integrating
//! law `corr += (avg - avg_prev)/(3 period) + beta*avg_prev/(27 period)`): on top of a
//! feed-forward the position is the integral of the step, so its integrator makes the
//! loop overshoot, and in the first seconds it integrates the early lines' slope error as
//! well. In `align::sim::Rig` (+87 ppm, 50–200 µs jitter) a run starting 3 samples off
//! (the lines of the first 50 ms) swung to −0.73 sample (seed 3) or −0.88 (a master
//! without jitter) 2 s later and came back over 6 s: that, not the lines, was the lock
//! time of 9–13.5 s (`examples/lockdiag.rs`). With this law the same runs lock in
//! 1.6–3.0 s. `corr` is clamped to `1 ± MAX_CORRECTION`.

/// The largest correction of the feed-forward step (2000 ppm).
pub const MAX_CORRECTION: f64 = 2e-3;

/// The controller's state (the last correction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateControl {
    corr: f64,
}

impl RateControl {
    /// A controller at rest (no correction).
    pub fn new() -> RateControl {
        RateControl { corr: 1.0 }
    }

    /// Feeds the position error (frames) with the controller's time constant `period`
    /// (frames); returns the correction factor of the step.
    pub fn update(&mut self, error: f64, period: f64) -> f64 {
        self.corr = (1.0 + error / period.max(1.0)).clamp(1.0 - MAX_CORRECTION, 1.0 + MAX_CORRECTION);
        self.corr
    }
}

impl Default for RateControl {
    fn default() -> RateControl {
        RateControl::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plant consuming `true_step` per frame while the controller steers `step*corr`
    /// (the feed-forward right, the position 3 frames off): the error decays without
    /// changing sign, to below 1e-3 frame within 8 time constants.
    #[test]
    fn the_controller_drives_a_position_error_to_zero_without_overshoot() {
        let (n, period) = (480.0, 12_000.0);
        let mut ctl = RateControl::new();
        let mut err: f64 = 3.0;
        for _ in 0..200 {
            let corr = ctl.update(err, period);
            err -= n * (corr - 1.0);
            assert!(err > 0.0, "the error overshot to {err}");
        }
        assert!(err.abs() < 1e-3, "the error stayed at {err}");
    }

    /// The feed-forward 300 ppm off: the error settles at the step error times the period.
    #[test]
    fn a_feed_forward_error_leaves_its_error_times_the_period() {
        let (n, period, d) = (480.0, 12_000.0, 3e-4);
        let mut ctl = RateControl::new();
        let mut err = 0.0;
        for _ in 0..2000 {
            let corr = ctl.update(err, period);
            err += n * (1.0 - (1.0 - d) * corr);
        }
        assert!((err - d * period).abs() < 0.01 * d * period, "the error settled at {err}");
    }
}
