//! The device-clock rate estimator: a second-order delay-locked loop (DLL) over
//! (frames, CLOCK_MONOTONIC) pairs, after F. Adriaensen, "Using a DLL to filter time"
//! (2005), the loop JACK and PipeWire use for the same purpose.
//!
//! The seed's PipeWire rate controller (shared/seeds/pipewire-bluez5-decode-buffer.h.txt)
//! was empty in this checkout, so this is an equivalent written from the published loop:
//! every `period` frames the device delivers a chunk at time `t`; the loop predicts `t1`,
//! the time of the next chunk, and `e2`, the period duration, and corrects both with the
//! prediction error `e = t - t1`:
//!
//! ```text
//!   t1 <- t1 + b*e + e2        b = sqrt(2)*w,  c = w^2,  w = 2*pi*B*e2
//!   e2 <- e2 + c*e             rate = period / e2
//! ```
//!
//! B is the loop bandwidth in Hz. It starts wide (fast lock) and narrows as the loop runs
//! (1 Hz for the first second of device time, 0.25 Hz up to 4 s, then 0.05 Hz), and `w` is
//! capped at 0.5 so that very long periods stay stable. A gap in the updates (an overrun,
//! a restart) calls [`RateDll::reset`]: the next update re-anchors `t1` and keeps `e2`.

use std::f64::consts::{PI, SQRT_2};

/// The DLL state.
#[derive(Clone, Debug)]
pub struct RateDll {
    period_frames: f64,
    origin_ns: Option<u64>,
    t1: f64,
    e2: f64,
    anchored: bool,
    elapsed: f64,
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
            anchored: false,
            elapsed: 0.0,
        }
    }

    /// Forgets the time anchor (after a gap); the period estimate is kept.
    pub fn reset(&mut self) {
        self.anchored = false;
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

    /// Feeds the time (CLOCK_MONOTONIC ns) at which the next period arrived; returns the
    /// rate estimate in Hz.
    pub fn update(&mut self, t_ns: u64) -> f64 {
        let origin = *self.origin_ns.get_or_insert(t_ns);
        let t = (t_ns as f64 - origin as f64) * 1e-9;
        if !self.anchored {
            self.t1 = t + self.e2;
            self.anchored = true;
            return self.rate();
        }
        let e = t - self.t1;
        if e.abs() > 8.0 * self.e2 {
            // A jump no loop should follow (a stall or a clock step): re-anchor.
            self.t1 = t + self.e2;
            return self.rate();
        }
        let w = (2.0 * PI * self.bandwidth() * self.e2).min(0.5);
        self.t1 += SQRT_2 * w * e + self.e2;
        self.e2 += w * w * e;
        self.elapsed += self.e2;
        self.rate()
    }

    /// The current estimate in Hz.
    pub fn rate(&self) -> f64 {
        self.period_frames / self.e2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A device 100 ppm fast, observed with ±200 µs of deterministic pseudo-random jitter.
    #[test]
    fn the_loop_finds_a_device_running_100_ppm_fast_through_jitter() {
        let (nominal, period) = (48_000.0, 480u32);
        let true_rate = nominal * (1.0 + 100e-6);
        let mut dll = RateDll::new(nominal, period);
        let mut seed = 12345u64;
        let mut rate = 0.0;
        for k in 0..3000u64 {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let jitter = ((seed >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 400e-6;
            let t = 1.0 + k as f64 * f64::from(period) / true_rate + jitter;
            rate = dll.update((t * 1e9) as u64);
        }
        let ppm = (rate / true_rate - 1.0) * 1e6;
        assert!(ppm.abs() < 5.0, "estimate {rate} Hz is {ppm} ppm off {true_rate} Hz");
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
}
