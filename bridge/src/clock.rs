//! Clock-offset estimation between the source's CLOCK_MONOTONIC and ours, in the manner of
//! Lab Streaming Layer: periodic probes of the source's clock queryable, each round a short
//! burst of which only the smallest round trip counts (the one least disturbed by queueing),
//! and a straight line fitted through the last minute of rounds for the drift. The drift
//! estimate is smoothed with a first-order low-pass, as the decode-buffer rate controller of
//! the PipeWire seed smooths its rate correction, so one odd round cannot swing it.
//!
//! offset = source_clock - local_clock at the same instant; a source timestamp `t_s` maps to
//! the local clock as `t_s - offset`. Uncertainty: half the best round trip of the window.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{anyhow, Result};
use zenoh::Wait;

/// Probes per round; the one with the smallest round trip is kept.
const BURST: usize = 4;
/// Rounds older than this leave the fit.
const WINDOW_NS: u64 = 60_000_000_000;
/// Low-pass weight of a new drift value.
const DRIFT_ALPHA: f64 = 0.2;

/// One round: the local mid-point, the offset seen and the round trip.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Round {
    /// Local CLOCK_MONOTONIC half-way through the best probe.
    pub local_ns: u64,
    /// Source minus local (ns).
    pub offset_ns: i64,
    /// Round trip of the best probe (ns).
    pub rtt_ns: u64,
}

/// The estimate's state; pure, so it is tested without a network.
#[derive(Debug, Default)]
pub struct Fit {
    rounds: VecDeque<Round>,
    drift: Option<f64>,
}

impl Fit {
    /// Adds a round and refits.
    pub fn add(&mut self, r: Round) {
        self.rounds.push_back(r);
        while self.rounds.front().is_some_and(|f| r.local_ns.saturating_sub(f.local_ns) > WINDOW_NS) {
            self.rounds.pop_front();
        }
        if let Some(slope) = self.slope() {
            self.drift = Some(match self.drift {
                Some(d) => d + DRIFT_ALPHA * (slope - d),
                None => slope,
            });
        }
    }

    /// Least-squares slope of offset over local time (ns/ns), once the window spans 5 s.
    fn slope(&self) -> Option<f64> {
        let (first, last) = (self.rounds.front()?, self.rounds.back()?);
        if self.rounds.len() < 3 || last.local_ns - first.local_ns < 5_000_000_000 {
            return None;
        }
        let n = self.rounds.len() as f64;
        let t0 = first.local_ns as f64;
        let o0 = first.offset_ns as f64;
        let (mut st, mut so, mut stt, mut sto) = (0.0, 0.0, 0.0, 0.0);
        for r in &self.rounds {
            let t = r.local_ns as f64 - t0;
            let o = r.offset_ns as f64 - o0;
            st += t;
            so += o;
            stt += t * t;
            sto += t * o;
        }
        let den = n * stt - st * st;
        (den.abs() > f64::EPSILON).then(|| (n * sto - st * so) / den)
    }

    /// The offset at local time `now` and its uncertainty: the best round of the window,
    /// carried to `now` with the smoothed drift.
    pub fn at(&self, now: u64) -> Option<(i64, u64)> {
        let best = self.rounds.iter().min_by_key(|r| r.rtt_ns)?;
        let drift = self.drift.unwrap_or(0.0);
        let dt = now as f64 - best.local_ns as f64;
        Some(((best.offset_ns as f64 + drift * dt).round() as i64, best.rtt_ns / 2))
    }

    /// Smoothed drift in parts per million.
    pub fn drift_ppm(&self) -> Option<f64> {
        self.drift.map(|d| d * 1e6)
    }
}

/// Probes in a thread and shares the fit.
pub struct ClockEstimator {
    fit: Arc<Mutex<Fit>>,
}

impl ClockEstimator {
    /// Starts probing `key` every `interval`.
    pub fn spawn(session: &zenoh::Session, key: String, interval: Duration) -> Result<ClockEstimator> {
        let fit = Arc::new(Mutex::new(Fit::default()));
        let shared = fit.clone();
        let session = session.clone();
        std::thread::Builder::new()
            .name("clock-probe".into())
            .spawn(move || loop {
                if let Some(r) = probe_round(&session, &key) {
                    shared.lock().unwrap_or_else(|e| e.into_inner()).add(r);
                }
                std::thread::sleep(interval);
            })
            .map_err(|e| anyhow!("spawn the clock prober: {e}"))?;
        Ok(ClockEstimator { fit })
    }

    /// Offset (source - local, ns) and uncertainty (ns) now.
    pub fn estimate(&self) -> (Option<i64>, Option<u64>) {
        let f = self.fit.lock().unwrap_or_else(|e| e.into_inner());
        match f.at(bassclient::sys::monotonic_ns()) {
            Some((o, u)) => (Some(o), Some(u)),
            None => (None, None),
        }
    }

    /// Smoothed drift (ppm).
    pub fn drift_ppm(&self) -> Option<f64> {
        self.fit.lock().unwrap_or_else(|e| e.into_inner()).drift_ppm()
    }
}

fn probe_round(session: &zenoh::Session, key: &str) -> Option<Round> {
    let mut best: Option<Round> = None;
    for _ in 0..BURST {
        let t0 = bassclient::sys::monotonic_ns();
        let replies = session.get(key).timeout(Duration::from_millis(500)).wait().ok()?;
        let Ok(reply) = replies.recv() else { continue };
        let t1 = bassclient::sys::monotonic_ns();
        let Ok(sample) = reply.result() else { continue };
        let bytes = sample.payload().to_bytes();
        let Ok(b) = <[u8; 8]>::try_from(&bytes[..]) else { continue };
        let remote = u64::from_le_bytes(b);
        let mid = t0 + (t1 - t0) / 2;
        let r = Round { local_ns: mid, offset_ns: remote as i64 - mid as i64, rtt_ns: t1 - t0 };
        if best.map_or(true, |b| r.rtt_ns < b.rtt_ns) {
            best = Some(r);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_smallest_round_trip_wins_and_a_steady_drift_is_found() {
        let mut f = Fit::default();
        // True offset 1 ms growing by 50 ppm; odd rounds carry 400 us of one-way queueing.
        for k in 0..61u64 {
            let t = 1_000_000_000 + k * 1_000_000_000;
            let truth = 1_000_000.0 + 50e-6 * (t - 1_000_000_000) as f64;
            let (skew, rtt) = if k % 2 == 1 { (400_000, 900_000) } else { (0, 100_000) };
            f.add(Round { local_ns: t, offset_ns: truth as i64 + skew, rtt_ns: rtt });
        }
        let now = 61_000_000_000;
        let (off, unc) = f.at(now).unwrap();
        let truth = 1_000_000.0 + 50e-6 * (now - 1_000_000_000) as f64;
        assert_eq!(unc, 50_000);
        // The fit sees the queueing rounds too; their bias is bounded by the skew.
        assert!((off as f64 - truth).abs() < 400_000.0, "offset {off} vs {truth}");
        let ppm = f.drift_ppm().unwrap();
        assert!((ppm - 50.0).abs() < 5.0, "drift {ppm} ppm");
    }

    #[test]
    fn no_rounds_no_estimate() {
        assert_eq!(Fit::default().at(5), None);
    }
}
