//! Clock-offset estimation between the source's CLOCK_MONOTONIC and ours, in the manner of
//! Lab Streaming Layer: periodic probes of the source's clock queryable, each round a short
//! burst of which only the smallest round trip counts (the one least disturbed by queueing),
//! and a straight line fitted through the last minute of rounds for the drift. The drift
//! estimate is smoothed with a first-order low-pass, as the decode-buffer rate controller of
//! the PipeWire seed smooths its rate correction, so one odd round cannot swing it.
//!
//! offset = source_clock - local_clock at the same instant; a source timestamp `t_s` maps to
//! the local clock as `t_s - offset`. Each round of the window, carried to now with the drift,
//! says the offset lies within half its round trip plus the drift's possible error times its
//! age; the map is the middle of where those intervals meet, the uncertainty half the overlap.
//!
//! Answers are not trusted (any peer may answer the query, beside the real `serve`):
//! - an answer that is not 8 bytes is ignored; answers to one probe that disagree (the
//!   source and another peer both answer) are all ignored: none is known to be the source's;
//! - a sample (one answer) says the offset lies within its round trip's half either side;
//!   two samples agree when those intervals meet. A round is the best sample of the largest
//!   group that agrees, and only if that group is a strict majority of the round's samples
//!   and has at least two: one reply is never adopted;
//! - a sample is refused if it contradicts the chunk stamps: a chunk queued at source time
//!   `s` that arrived at local time `l` says offset >= `s - l` (and, for the least delayed
//!   chunk, not much more);
//! - no estimate before [`MIN_ROUNDS`] rounds agree; once there is one, a round that
//!   contradicts it (beyond both uncertainties) is refused, unless [`RESET_ROUNDS`] rounds in
//!   a row agree with each other on a new value (the source's clock did change).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{anyhow, Result};
use zenoh::Wait;

/// Probes per round; the one with the smallest round trip is kept.
const BURST: usize = 4;
/// Pause between rounds until there is an estimate ([`MIN_ROUNDS`] agreeing rounds), when
/// shorter than the probe interval: the first bound comes within a fraction of a second.
const FIRST_ROUNDS_PAUSE: Duration = Duration::from_millis(50);
/// Rounds older than this leave the fit.
const WINDOW_NS: u64 = 60_000_000_000;
/// Low-pass weight of a new drift value.
const DRIFT_ALPHA: f64 = 0.2;
/// Rounds that must agree before there is an estimate.
pub const MIN_ROUNDS: usize = 3;
/// Consecutive refused rounds, agreeing with each other, that replace the estimate.
pub const RESET_ROUNDS: usize = 5;
/// Slack of agreement tests beyond the round trips (scheduling, unknown drift).
const TOLERANCE_NS: f64 = 1_000_000.0;
/// Drift assumed at most while comparing with an older round (parts per unit).
const MAX_DRIFT: f64 = 200e-6;
/// Drift allowed for in the uncertainty before the fit has one (parts per unit): two hosts'
/// crystals of ±50 ppm each. docs/time.md, "Bounds".
const UNFIT_DRIFT: f64 = 100e-6;
/// Chunk stamps older than this leave the bound.
const CHUNK_WINDOW_NS: u64 = 10_000_000_000;
/// How much more than the least-delayed chunk's bound the offset may be (a chunk's delay
/// from queueing at the source to arrival, in the best case of the window: batching with
/// `serve --chunks-per-message` adds up to 63 chunk periods).
const CHUNK_SLACK_NS: i64 = 10_000_000_000;

/// The clock map at one instant: source − local offset and its uncertainty (ns), from
/// [`ClockEstimator::map`]; a source stamp `t_s` maps to `t_s − offset_ns`, within
/// `± uncertainty_ns` of where the source's clock put it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ClockMap {
    /// Source minus local (ns).
    pub offset_ns: i64,
    /// Bound of the offset's error (ns).
    pub uncertainty_ns: u64,
}

/// Whether a round trip `rtt` is within twice the window's best (or 50 µs of it): its offset
/// is then about as good as the best's.
fn good_trip(rtt: u64, best: u64) -> bool {
    rtt <= (2 * best).max(best + 50_000)
}

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

impl Round {
    /// Whether two samples' intervals (offset ± rtt/2) meet, with `slack` ns more.
    fn agrees(&self, o: &Round, slack: f64) -> bool {
        let d = (self.offset_ns as f64 - o.offset_ns as f64).abs();
        d <= (self.rtt_ns as f64 + o.rtt_ns as f64) / 2.0 + slack
    }
}

/// The round made of one burst's samples (every answer of every probe): the smallest round
/// trip among the largest group of samples that agree, if that group has two samples or more
/// and is a strict majority; `None` otherwise (one answer, or answers that disagree).
pub fn consensus(samples: &[Round]) -> Option<Round> {
    let mut best: Option<(usize, Round)> = None;
    for s in samples {
        let n = samples.iter().filter(|o| s.agrees(o, TOLERANCE_NS)).count();
        let better = match best {
            None => true,
            Some((bn, b)) => n > bn || (n == bn && s.rtt_ns < b.rtt_ns),
        };
        if better {
            best = Some((n, *s));
        }
    }
    let (n, r) = best?;
    (n >= 2 && 2 * n > samples.len()).then_some(r)
}

/// The estimate's state; pure, so it is tested without a network.
#[derive(Debug, Default)]
pub struct Fit {
    rounds: VecDeque<Round>,
    drift: Option<f64>,
    /// Refused rounds in a row (candidates for a new estimate).
    refused_streak: Vec<Round>,
    /// Chunk stamps: (local arrival ns, source stamp - local arrival ns).
    chunks: VecDeque<(u64, i64)>,
    /// Samples and rounds refused so far.
    refused: u64,
    /// [`Fit::drift_error`] as of the last round taken.
    drift_err: Option<f64>,
}

impl Fit {
    /// Records a chunk of the followed source stamped `source_ns` (source clock, when it was
    /// queued) that arrived at local time `local_ns`: the offset is at least their difference.
    pub fn observe_chunk(&mut self, source_ns: u64, local_ns: u64) {
        if source_ns == 0 {
            return;
        }
        let lo = (source_ns as i128 - local_ns as i128).clamp(i64::MIN as i128, i64::MAX as i128) as i64;
        self.chunks.push_back((local_ns, lo));
        while self.chunks.front().is_some_and(|&(t, _)| local_ns.saturating_sub(t) > CHUNK_WINDOW_NS) {
            self.chunks.pop_front();
        }
        if self.chunks.len() > 4096 {
            self.chunks.pop_front();
        }
    }

    /// Whether an offset contradicts the chunk stamps of the window.
    pub fn contradicts_chunks(&self, offset_ns: i64, rtt_ns: u64) -> bool {
        let Some(lo) = self.chunks.iter().map(|&(_, lo)| lo).max() else { return false };
        let half = (rtt_ns / 2).min(i64::MAX as u64) as i64;
        offset_ns.saturating_add(half) < lo.saturating_sub(TOLERANCE_NS as i64)
            || offset_ns.saturating_sub(half) > lo.saturating_add(CHUNK_SLACK_NS)
    }

    /// Counts a sample or round refused outside [`Fit::add`] (malformed answers).
    pub fn count_refused(&mut self, n: u64) {
        self.refused += n;
    }

    /// Samples and rounds refused so far.
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// Adds a round if it agrees with the estimate (or there is none yet) and refits;
    /// returns whether it was taken.
    pub fn add(&mut self, r: Round) -> bool {
        if self.contradicts_chunks(r.offset_ns, r.rtt_ns) {
            self.refused += 1;
            return false;
        }
        if self.rounds.len() >= MIN_ROUNDS {
            if let Some((predicted, unc)) = self.at(r.local_ns) {
                let best_age = self.best().map_or(0, |b| r.local_ns.saturating_sub(b.local_ns));
                let slack = unc as f64 + r.rtt_ns as f64 / 2.0 + TOLERANCE_NS + MAX_DRIFT * best_age as f64;
                if (r.offset_ns as f64 - predicted as f64).abs() > slack {
                    self.refused += 1;
                    self.refused_streak.push(r);
                    let n = self.refused_streak.len();
                    let agree =
                        self.refused_streak.iter().all(|o| o.agrees(&self.refused_streak[0], TOLERANCE_NS));
                    if n >= RESET_ROUNDS && agree {
                        // The source's clock changed (a rebooted source): the new value holds.
                        self.rounds = std::mem::take(&mut self.refused_streak).into();
                        self.drift = None;
                        self.drift_err = None;
                    } else if !agree {
                        self.refused_streak = vec![r];
                    }
                    return false;
                }
            }
        } else if let Some(b) = self.best() {
            if !r.agrees(&b, TOLERANCE_NS) {
                // Before an estimate exists, disagreeing rounds start the count again.
                self.refused += self.rounds.len() as u64;
                self.rounds.clear();
                self.drift = None;
            }
        }
        self.refused_streak.clear();
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
        self.drift_err = Some(self.drift_error());
        true
    }

    fn best(&self) -> Option<Round> {
        self.rounds.iter().min_by_key(|r| r.rtt_ns).copied()
    }

    /// Least-squares slope of offset over local time (ns/ns), once the window spans 5 s.
    fn slope(&self) -> Option<f64> {
        self.slope_fit().map(|(b, _)| b)
    }

    /// The slope and its standard error (both ns/ns), once the good rounds span 5 s: only
    /// rounds whose round trip is near the window's best ([`Fit::good`]) are fitted, since a
    /// long round trip may hide an asymmetric delay of up to its length.
    fn slope_fit(&self) -> Option<(f64, f64)> {
        let best = self.rounds.iter().map(|r| r.rtt_ns).min()?;
        let good: Vec<&Round> = self.rounds.iter().filter(|r| good_trip(r.rtt_ns, best)).collect();
        let (first, last) = (good.first()?, good.last()?);
        if good.len() < 3 || last.local_ns - first.local_ns < 5_000_000_000 {
            return None;
        }
        let n = good.len() as f64;
        let t0 = first.local_ns as f64;
        let o0 = first.offset_ns as f64;
        let (mut st, mut so, mut stt, mut sto) = (0.0, 0.0, 0.0, 0.0);
        for r in &good {
            let t = r.local_ns as f64 - t0;
            let o = r.offset_ns as f64 - o0;
            st += t;
            so += o;
            stt += t * t;
            sto += t * o;
        }
        let den = n * stt - st * st;
        if den.abs() <= f64::EPSILON {
            return None;
        }
        let b = (n * sto - st * so) / den;
        let a = (so - b * st) / n;
        let ss: f64 = good
            .iter()
            .map(|r| {
                let (t, o) = (r.local_ns as f64 - t0, r.offset_ns as f64 - o0);
                (o - a - b * t).powi(2)
            })
            .sum();
        // Standard error of the slope: residual variance over the spread of the times.
        let sxx = stt - st * st / n;
        let se = if n > 2.0 && sxx > 0.0 { (ss / (n - 2.0) / sxx).sqrt() } else { f64::INFINITY };
        Some((b, se))
    }

    /// How wrong the drift used by [`Fit::at`] may be (ns/ns): before the fit spans 5 s, the
    /// drift two hosts' crystals may have ([`UNFIT_DRIFT`]); then three standard errors of the
    /// fitted slope plus how far the smoothed drift lags it.
    fn drift_error(&self) -> f64 {
        match (self.slope_fit(), self.drift) {
            (Some((b, se)), Some(d)) if se.is_finite() => ((d - b).abs() + 3.0 * se).min(MAX_DRIFT),
            _ => UNFIT_DRIFT,
        }
    }

    /// The offset at local time `now` and its uncertainty. Every round of the window, carried
    /// to `now` with the smoothed drift, says the offset lies within half its round trip plus
    /// the drift's possible error over its age ([`Fit::drift_error`]); the map is the middle
    /// of where all those intervals meet, its uncertainty half that overlap. Each interval
    /// holds the truth whatever the two ways' delays were (neither is negative), so their
    /// overlap does, and it is narrower than the best single round's when rounds' queueing
    /// differs (random delays each way: the overlap's edges are set by different rounds).
    /// Should they not meet (a drift wrongly judged), the one round whose interval is
    /// narrowest is taken, as before the overlap was used.
    pub fn at(&self, now: u64) -> Option<(i64, u64)> {
        if self.rounds.len() < MIN_ROUNDS {
            return None;
        }
        let err = self.drift_err.unwrap_or(UNFIT_DRIFT);
        let drift = self.drift.unwrap_or(0.0);
        let carried = |r: &Round| {
            let dt = now as f64 - r.local_ns as f64;
            (r.offset_ns as f64 + drift * dt, r.rtt_ns as f64 / 2.0 + (err * dt.abs()).ceil())
        };
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for r in &self.rounds {
            let (centre, half) = carried(r);
            lo = lo.max(centre - half);
            hi = hi.min(centre + half);
        }
        if lo <= hi {
            return Some((((lo + hi) / 2.0).round() as i64, ((hi - lo) / 2.0).ceil() as u64 + 1));
        }
        let best = self.rounds.iter().map(carried).min_by(|a, b| a.1.total_cmp(&b.1))?;
        Some((best.0.round() as i64, best.1.ceil() as u64))
    }

    /// Smoothed drift in parts per million.
    pub fn drift_ppm(&self) -> Option<f64> {
        self.drift.map(|d| d * 1e6)
    }
}

/// Serve's side of keyed clock answers: a probe's attachment is `user_len u8, user, nonce
/// [16]`; the answer's is HMAC-SHA256(pair secret of (source, user) for "clock", key ‖ nonce ‖
/// time), so only the source can answer a mirror's probe (a peer that answers beside it is
/// refused).
pub struct ReplyKeys {
    keys: std::collections::HashMap<String, [u8; 32]>,
}

impl ReplyKeys {
    /// The keys for every identity `cred` trusts (one key agreement each, at start).
    pub fn new(cred: &crate::credentials::Credentials) -> ReplyKeys {
        let keys = cred
            .trusted
            .iter()
            .filter_map(|t| Some((t.name.clone(), cred.pair_secret(&cred.user, &t.name, "clock")?)))
            .collect();
        ReplyKeys { keys }
    }

    /// The answer's attachment for a probe with attachment `probe`, if it names a trusted user.
    pub fn answer(&self, key: &str, probe: &[u8], now: &[u8; 8]) -> Option<Vec<u8>> {
        let (&n, rest) = probe.split_first()?;
        let n = usize::from(n);
        if rest.len() != n + 16 {
            return None;
        }
        let k = self.keys.get(std::str::from_utf8(&rest[..n]).ok()?)?;
        Some(crate::credentials::mac(k, &[key.as_bytes(), &rest[n..], now]).to_vec())
    }
}

/// The mirror's side: its name and the key it shares with the source for clock answers.
pub struct ProbeKey {
    /// The mirror's identity.
    pub user: String,
    /// The pair secret of (source, mirror) for "clock".
    pub key: [u8; 32],
}

/// Probes in a thread and shares the fit.
pub struct ClockEstimator {
    fit: Arc<Mutex<Fit>>,
}

impl ClockEstimator {
    /// Starts probing `key` every `interval`.
    pub fn spawn(
        session: &zenoh::Session,
        key: String,
        interval: Duration,
        auth: Option<ProbeKey>,
    ) -> Result<ClockEstimator> {
        let fit = Arc::new(Mutex::new(Fit::default()));
        let shared = fit.clone();
        let session = session.clone();
        std::thread::Builder::new()
            .name("clock-probe".into())
            .spawn(move || loop {
                let (samples, malformed) = probe_burst(&session, &key, auth.as_ref());
                let mut f = shared.lock().unwrap_or_else(|e| e.into_inner());
                f.count_refused(malformed);
                let n = samples.len();
                let sane: Vec<Round> =
                    samples.into_iter().filter(|r| !f.contradicts_chunks(r.offset_ns, r.rtt_ns)).collect();
                f.count_refused((n - sane.len()) as u64);
                match consensus(&sane) {
                    Some(r) => {
                        f.add(r);
                    }
                    None if !sane.is_empty() => f.count_refused(1),
                    None => {}
                }
                let first = f.rounds.len() < MIN_ROUNDS;
                drop(f);
                std::thread::sleep(if first { interval.min(FIRST_ROUNDS_PAUSE) } else { interval });
            })
            .map_err(|e| anyhow!("spawn the clock prober: {e}"))?;
        Ok(ClockEstimator { fit })
    }

    fn fit(&self) -> std::sync::MutexGuard<'_, Fit> {
        self.fit.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Offset (source - local, ns) and uncertainty (ns) now.
    pub fn estimate(&self) -> (Option<i64>, Option<u64>) {
        match self.fit().at(bassport::sys::monotonic_ns()) {
            Some((o, u)) => (Some(o), Some(u)),
            None => (None, None),
        }
    }

    /// The clock map now, once there is an estimate.
    pub fn map(&self) -> Option<ClockMap> {
        let (o, u) = self.fit().at(bassport::sys::monotonic_ns())?;
        Some(ClockMap { offset_ns: o, uncertainty_ns: u })
    }

    /// Smoothed drift (ppm).
    pub fn drift_ppm(&self) -> Option<f64> {
        self.fit().drift_ppm()
    }

    /// Answers and rounds refused so far.
    pub fn refused(&self) -> u64 {
        self.fit().refused()
    }

    /// A chunk of the followed source, queued at source time `source_ns`, arrived at
    /// `local_ns` (see [`Fit::observe_chunk`]).
    pub fn observe_chunk(&self, source_ns: u64, local_ns: u64) {
        self.fit().observe_chunk(source_ns, local_ns);
    }
}

/// One burst: every answer of every probe (all of them: another peer may answer beside
/// the source) whose answers agree, and the number of answers refused (not 8 bytes, or
/// disagreeing with another answer to the same probe).
fn probe_burst(session: &zenoh::Session, key: &str, auth: Option<&ProbeKey>) -> (Vec<Round>, u64) {
    let mut samples = Vec::new();
    let mut malformed = 0;
    for i in 0..BURST {
        let mut nonce = [0u8; 16];
        nonce[..8].copy_from_slice(&bassport::sys::monotonic_ns().to_le_bytes());
        nonce[8..].copy_from_slice(&(i as u64 ^ crate::net::instance_id()).to_le_bytes());
        let attachment = auth.map(|a| {
            let mut b = vec![a.user.len() as u8];
            b.extend_from_slice(a.user.as_bytes());
            b.extend_from_slice(&nonce);
            b
        });
        let t0 = bassport::sys::monotonic_ns();
        let Ok(replies) = session
            .get(key)
            .attachment(attachment)
            .consolidation(zenoh::query::ConsolidationMode::None)
            .timeout(Duration::from_millis(500))
            .wait()
        else {
            continue;
        };
        // At most a few answers per probe are looked at: a flood of answers is not a sample.
        let mut answers = Vec::new();
        for _ in 0..8 {
            let Ok(reply) = replies.recv() else { break };
            let t1 = bassport::sys::monotonic_ns();
            let Ok(sample) = reply.result() else {
                malformed += 1;
                continue;
            };
            let bytes = sample.payload().to_bytes();
            let Ok(b) = <[u8; 8]>::try_from(&bytes[..]) else {
                malformed += 1;
                continue;
            };
            if let Some(a) = auth {
                let want = crate::credentials::mac(&a.key, &[key.as_bytes(), &nonce, &b]);
                let got = sample.attachment().map(|x| x.to_bytes().into_owned()).unwrap_or_default();
                if got != want {
                    malformed += 1;
                    continue;
                }
            }
            let remote = u64::from_le_bytes(b) as i128;
            let mid = t0 + (t1 - t0) / 2;
            let offset = (remote - mid as i128).clamp(i64::MIN as i128, i64::MAX as i128) as i64;
            answers.push(Round { local_ns: mid, offset_ns: offset, rtt_ns: t1 - t0 });
        }
        // Two answers to one probe that disagree (the source and another peer, or two
        // sources): none of them is known to be the source's.
        if answers.iter().all(|a| a.agrees(&answers[0], TOLERANCE_NS)) {
            samples.extend(answers);
        } else {
            malformed += answers.len() as u64;
        }
    }
    (samples, malformed)
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
        // No wider than the best round trip's half, and the truth inside.
        assert!(unc <= 50_001, "uncertainty {unc}");
        assert!((off as f64 - truth).abs() <= unc as f64, "offset {off} vs {truth} ± {unc}");
        let ppm = f.drift_ppm().unwrap();
        assert!((ppm - 50.0).abs() < 5.0, "drift {ppm} ppm");
    }

    #[test]
    fn no_rounds_no_estimate() {
        assert_eq!(Fit::default().at(5), None);
    }

    fn steady(f: &mut Fit, from: u64, n: u64, offset: i64) {
        for k in 0..n {
            assert!(f.add(Round { local_ns: from + k * 500_000_000, offset_ns: offset, rtt_ns: 200_000 }));
        }
    }

    #[test]
    fn one_reply_is_never_adopted_and_a_split_burst_gives_no_round() {
        let real = Round { local_ns: 10, offset_ns: 5_000, rtt_ns: 100_000 };
        let forged = Round { offset_ns: 270_000_000_000_000_000, ..real };
        assert_eq!(consensus(&[real]), None, "one answer");
        assert_eq!(consensus(&[real, forged]), None);
        assert_eq!(consensus(&[real, real, forged, forged]), None, "no majority");
        assert_eq!(consensus(&[real, forged, real, real]), Some(real));
        // And no estimate from fewer than MIN_ROUNDS rounds.
        let mut f = Fit::default();
        assert!(f.add(real));
        assert_eq!(f.at(10), None);
    }

    #[test]
    fn a_forged_offset_never_replaces_a_sane_estimate() {
        let mut f = Fit::default();
        steady(&mut f, 1_000_000_000, 10, 3_000);
        let forged = Round { local_ns: 6_000_000_000, offset_ns: 270_000_000_000_000_000, rtt_ns: 50_000 };
        for k in 0..(RESET_ROUNDS as u64 - 1) {
            assert!(!f.add(Round { local_ns: forged.local_ns + k, ..forged }));
        }
        let (off, _) = f.at(7_000_000_000).unwrap();
        assert!((off - 3_000).abs() < 1_000, "offset {off}");
        assert_eq!(f.refused(), RESET_ROUNDS as u64 - 1);
    }

    #[test]
    fn the_chunk_stamps_refuse_an_offset_they_contradict_even_a_persistent_one() {
        let mut f = Fit::default();
        // Same machine: chunks queued at source time t arrive 1 ms later here.
        for k in 0..20u64 {
            let t = 1_000_000_000 + k * 10_000_000;
            f.observe_chunk(t, t + 1_000_000);
        }
        assert!(!f.contradicts_chunks(0, 100_000));
        assert!(f.contradicts_chunks(270_000_000_000_000_000, 100_000));
        assert!(f.contradicts_chunks(-5_000_000_000, 100_000));
        for k in 0..(2 * RESET_ROUNDS as u64) {
            let r = Round { local_ns: 2_000_000_000 + k, offset_ns: 270_000_000_000_000_000, rtt_ns: 50_000 };
            assert!(!f.add(r), "a forged value agreeing with itself is still refused");
        }
        assert_eq!(f.at(3_000_000_000), None);
        steady(&mut f, 2_000_000_000, 3, 0);
        assert_eq!(f.at(3_000_000_000).map(|(o, _)| o), Some(0));
    }

    #[test]
    fn a_real_change_of_the_source_clock_is_taken_after_several_agreeing_rounds() {
        let mut f = Fit::default();
        steady(&mut f, 1_000_000_000, 10, 3_000);
        let moved = 50_000_000_000i64;
        for k in 0..RESET_ROUNDS as u64 {
            f.add(Round { local_ns: 7_000_000_000 + k * 500_000_000, offset_ns: moved, rtt_ns: 200_000 });
        }
        assert_eq!(f.at(10_000_000_000).map(|(o, _)| o), Some(moved));
    }

    #[test]
    fn the_overlap_of_jittered_rounds_is_narrower_than_the_best_round_and_holds_the_truth() {
        // Delays of 0..200 us each way (a xorshift sequence), 50 us of base delay each way,
        // a true offset 3 ms growing by 20 ppm; a round every 0.5 s for 40 s. At every round
        // the truth lies within the map's uncertainty; after 10 s the overlap is narrower than,
        // and much closer to the truth than, the one round of least carried uncertainty (the map
        // before the overlap was used).
        let mut x: u64 = 0x1234_5678_9abc_def1;
        let mut rnd = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x % 200_001) as f64
        };
        let truth = |t: u64| 3_000_000.0 + 20e-6 * t as f64;
        let single = |f: &Fit, now: u64| {
            let (err, drift) = (f.drift_err.unwrap_or(UNFIT_DRIFT), f.drift.unwrap_or(0.0));
            f.rounds
                .iter()
                .map(|r| {
                    let dt = now as f64 - r.local_ns as f64;
                    (r.offset_ns as f64 + drift * dt, r.rtt_ns as f64 / 2.0 + err * dt.abs())
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap()
        };
        let mut f = Fit::default();
        let (mut new, mut old) = (Vec::new(), Vec::new());
        for k in 1..=80u64 {
            let t = k * 500_000_000;
            let (out, back) = (50_000.0 + rnd(), 50_000.0 + rnd());
            let offset = truth(t) + (back - out) / 2.0;
            f.add(Round { local_ns: t, offset_ns: offset.round() as i64, rtt_ns: (out + back) as u64 });
            if let Some((o, u)) = f.at(t) {
                let e = (o as f64 - truth(t)).abs();
                assert!(e <= u as f64, "round {k}: error {e} ns outside ±{u} ns");
                if k > 20 {
                    let (so, su) = single(&f, t);
                    new.push((e, u as f64));
                    old.push(((so - truth(t)).abs(), su));
                }
            }
        }
        let mean = |v: &[(f64, f64)], i: usize| {
            v.iter().map(|p| if i == 0 { p.0 } else { p.1 }).sum::<f64>() / v.len() as f64
        };
        let (new_e, new_u, old_e, old_u) = (mean(&new, 0), mean(&new, 1), mean(&old, 0), mean(&old, 1));
        // Measured: error 11.2 vs 19.2 us, uncertainty ±75.9 vs ±86.8 us (the drift's possible
        // error over the rounds' ages widens the older rounds' intervals: most of the width).
        assert!(new_u < 0.95 * old_u, "overlap ±{new_u} ns vs one round's ±{old_u} ns");
        assert!(new_e < 0.75 * old_e, "overlap error {new_e} ns vs one round's {old_e} ns");
    }
}
