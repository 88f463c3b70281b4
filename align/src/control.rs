//! The rate controller: PipeWire's bluez5 decode-buffer controller (the seed), on the
//! follower's position error instead of a buffer level.
//!
//! With `beta = duration/period`, every chunk it iterates
//!
//! ```text
//!   avg  <- (1 - beta)*avg + beta*error
//!   corr <- corr + (1/3)*(avg - avg_prev)/period + (beta/27)*avg_prev/period
//! ```
//!
//! `error` is the target follower position minus the resampler's (frames), `duration`
//! the frames of the chunk and `period` the averaging period (frames). The poles sit
//! near `(1 - beta)^(1/3)`: the error converges to zero without sign changes in its step
//! response, and `corr` is low-pass filtered, so stamp noise that reaches the target
//! position is smoothed before it reaches the ratio. `corr` multiplies the step the two
//! time lines give (the feed-forward) and is clamped to `1 ± MAX_CORRECTION`.

/// The largest correction of the feed-forward step (2000 ppm).
pub const MAX_CORRECTION: f64 = 2e-3;

/// The controller's state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateControl {
    avg: f64,
    corr: f64,
}

impl RateControl {
    /// A controller at rest (no error, no correction).
    pub fn new() -> RateControl {
        RateControl { avg: 0.0, corr: 1.0 }
    }

    /// Feeds the position error of a chunk of `duration` frames; returns the correction
    /// factor of the step.
    pub fn update(&mut self, error: f64, duration: f64, period: f64) -> f64 {
        let beta = (duration / period).clamp(0.0, 0.5);
        let avg = beta * error + (1.0 - beta) * self.avg;
        self.corr += (1.0 / 3.0) * (avg - self.avg) / period + (beta / 27.0) * self.avg / period;
        self.avg = avg;
        self.corr = self.corr.clamp(1.0 - MAX_CORRECTION, 1.0 + MAX_CORRECTION);
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
    /// (the feed-forward 300 ppm off): the position error settles to zero.
    #[test]
    fn the_controller_drives_a_position_error_to_zero() {
        let (true_step, ff, n, period) = (1.0, 1.0 - 3e-4, 480.0, 24_000.0);
        let mut ctl = RateControl::new();
        let mut err = 2.0;
        for _ in 0..3000 {
            let corr = ctl.update(err, n, period);
            err += n * (true_step - ff * corr);
        }
        assert!(err.abs() < 1e-3, "the error stayed at {err}");
    }
}
