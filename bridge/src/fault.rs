//! Deterministic fault injection for the network tests, reachable only from the test binary
//! `bass-bridge-faults` (`--fault drop=S,dup=S,reorder=S,delay=S serve ...`): drops, duplicates, swaps with the next
//! message, or holds back by four messages the message of sequence number S;
//! `control-delay=MS` holds every forwarded control request MS milliseconds before it goes to
//! the broker (to have many in progress at once); `clock-delay=US` holds every clock answer US
//! microseconds after its time was read (an asymmetric path: the answer's way back is longer
//! than the probe's way out, the case a round trip's half cannot see); `clock-jitter=US` holds
//! each clock probe a pseudo-random 0..=US microseconds before its time is read and its
//! answer another 0..=US after (jitter both ways); `clock-offset=US` (signed) and
//! `clock-skew=PPM` (signed) present the source's CLOCK_MONOTONIC, in the clock answers and in
//! the chunks' stamps alike, moved by the offset and running PPM fast from serve's start (a
//! second host's clock, whose truth the tests still know); `realtime-step=MS:S` steps the
//! chunks' CLOCK_REALTIME stamps by MS milliseconds (signed) from S seconds after serve's
//! start on (an NTP step of the source host's wall clock, which must not move the mapping).
//! The installed `bass-bridge` has no such option.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use anyhow::{bail, Result};

/// What happens to one sequence number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Action {
    Drop,
    Dup,
    Reorder,
    Delay,
}

/// The fault plan and the messages it holds back.
#[derive(Default)]
pub struct Faults {
    plan: Vec<(u64, Action)>,
    held: Vec<(u64, Vec<u8>)>,
    control_delay: Duration,
    clock: ClockFaults,
}

/// What the fault build does to the source's clock: its answers' timing (`clock-delay`,
/// `clock-jitter`) and the clock itself ([`SourceClock`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClockFaults {
    /// Every answer held this long after its time was read.
    pub delay: Duration,
    /// Up to this long before the time is read and again after, pseudo-random.
    pub jitter: Duration,
    /// The clock the answers and the chunks' stamps are read on.
    pub source: SourceClock,
}

/// The source's clock as the fault build presents it: the real CLOCK_MONOTONIC plus an
/// offset, running `skew` (ns/ns) fast from `origin_ns`; CLOCK_REALTIME stamps stepped by
/// `realtime_step_ns` from `origin_ns + realtime_step_after_ns` on. The default is the real
/// clock, unchanged.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SourceClock {
    offset_ns: i64,
    skew: f64,
    origin_ns: u64,
    realtime_step_ns: i64,
    realtime_step_after_ns: u64,
}

impl SourceClock {
    /// The presented CLOCK_MONOTONIC of real instant `t_ns`.
    pub fn mono(&self, t_ns: u64) -> u64 {
        if self.offset_ns == 0 && self.skew == 0.0 {
            return t_ns;
        }
        let since = t_ns as f64 - self.origin_ns as f64;
        let moved = t_ns as i128 + self.offset_ns as i128 + (since * self.skew).round() as i128;
        moved.clamp(1, u64::MAX as i128) as u64
    }

    /// The presented CLOCK_REALTIME stamp `rt_ns` of a chunk stamped at real instant `t_ns`.
    pub fn realtime(&self, rt_ns: u64, t_ns: u64) -> u64 {
        let stepped =
            self.realtime_step_ns != 0 && t_ns >= self.origin_ns.saturating_add(self.realtime_step_after_ns);
        if !stepped || rt_ns == 0 {
            return rt_ns;
        }
        (rt_ns as i128 + self.realtime_step_ns as i128).clamp(1, u64::MAX as i128) as u64
    }
}

/// A pseudo-random duration in 0..=`max` (xorshift64*; the sequence is the same every run).
pub fn jitter(state: &AtomicU64, max: Duration) -> Duration {
    if max.is_zero() {
        return Duration::ZERO;
    }
    let mut x = state.load(Ordering::Relaxed) | 1;
    x ^= x >> 12;
    x ^= x << 25;
    x ^= x >> 27;
    state.store(x, Ordering::Relaxed);
    let r = x.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11; // 53 random bits
    max.mul_f64(r as f64 / (1u64 << 53) as f64)
}

impl Faults {
    /// Parses `--fault`.
    pub fn parse(spec: Option<&str>) -> Result<Faults> {
        let Some(spec) = spec else { return Ok(Faults::default()) };
        let mut plan = Vec::new();
        let mut control_delay = Duration::ZERO;
        let mut clock = ClockFaults::default();
        clock.source.origin_ns = bassport::sys::monotonic_ns();
        for item in spec.split(',').filter(|s| !s.is_empty()) {
            let Some((what, seq)) = item.split_once('=') else {
                bail!("--fault item {item:?}: use what=SEQ")
            };
            let number = || -> Result<u64> {
                seq.parse().map_err(|e| {
                    anyhow::anyhow!("--fault item {item:?}: {seq:?} is not a whole number ({e})")
                })
            };
            if what == "control-delay" {
                control_delay = Duration::from_millis(number()?);
                continue;
            }
            let signed = || -> Result<i64> {
                seq.parse().map_err(|e| {
                    anyhow::anyhow!("--fault item {item:?}: {seq:?} is not a whole number ({e})")
                })
            };
            match what {
                "clock-delay" => clock.delay = Duration::from_micros(number()?),
                "clock-jitter" => clock.jitter = Duration::from_micros(number()?),
                "clock-offset" => clock.source.offset_ns = signed()?.saturating_mul(1000),
                "clock-skew" => {
                    let ppm = signed()?;
                    if ppm.abs() > 1000 {
                        bail!("--fault item {item:?}: {ppm} ppm is out of range (-1000 to 1000)");
                    }
                    clock.source.skew = ppm as f64 * 1e-6;
                }
                "realtime-step" => {
                    let bad =
                        || anyhow::anyhow!("--fault item {item:?}: use realtime-step=MS:S (whole numbers)");
                    let (ms, at) = seq.split_once(':').ok_or_else(bad)?;
                    clock.source.realtime_step_ns =
                        ms.parse::<i64>().map_err(|_| bad())?.saturating_mul(1_000_000);
                    clock.source.realtime_step_after_ns =
                        at.parse::<u64>().map_err(|_| bad())?.saturating_mul(1_000_000_000);
                }
                _ => {}
            }
            if what.starts_with("clock-") || what == "realtime-step" {
                continue;
            }
            let a = match what {
                "drop" => Action::Drop,
                "dup" => Action::Dup,
                "reorder" => Action::Reorder,
                "delay" => Action::Delay,
                _ => bail!(
                    "--fault: unknown fault {what:?} (drop, dup, reorder, delay, control-delay, \
                     clock-delay, clock-jitter, clock-offset, clock-skew, realtime-step)"
                ),
            };
            plan.push((number()?, a));
        }
        Ok(Faults { plan, held: Vec::new(), control_delay, clock })
    }

    /// What is done to the source's clock and its answers (the default: nothing).
    pub fn clock(&self) -> ClockFaults {
        self.clock
    }

    /// How long each forwarded control request is held (`control-delay=MS`; zero without).
    pub fn control_delay(&self) -> Duration {
        self.control_delay
    }

    /// The messages to put now for message `seq`, in order.
    pub fn apply(&mut self, seq: u64, bytes: Vec<u8>) -> Vec<Vec<u8>> {
        if self.plan.is_empty() && self.held.is_empty() {
            return vec![bytes]; // the installed binary: no faults
        }
        let action = self.plan.iter().find(|(s, _)| *s == seq).map(|(_, a)| *a);
        let mut out = Vec::new();
        match action {
            Some(Action::Drop) => {}
            Some(Action::Dup) => {
                out.push(bytes.clone());
                out.push(bytes);
            }
            // Released after the next message (reorder) or after four more (delay).
            Some(Action::Reorder) => self.held.push((seq + 1, bytes)),
            Some(Action::Delay) => self.held.push((seq + 4, bytes)),
            None => out.push(bytes),
        }
        let (due, keep): (Vec<_>, Vec<_>) =
            std::mem::take(&mut self.held).into_iter().partition(|(at, _)| *at <= seq);
        self.held = keep;
        out.extend(due.into_iter().map(|(_, b)| b));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_fault_acts_on_its_sequence_number_only() {
        let mut f = Faults::parse(Some("drop=1,dup=2,reorder=3,delay=5")).unwrap();
        let mut seen = Vec::new();
        for s in 0..12u64 {
            for b in f.apply(s, vec![s as u8]) {
                seen.push(b[0]);
            }
        }
        assert_eq!(seen, vec![0, 2, 2, 4, 3, 6, 7, 8, 9, 5, 10, 11]);
    }

    #[test]
    fn the_control_delay_is_parsed_and_bad_numbers_are_named() {
        let f = Faults::parse(Some("control-delay=2000,drop=3")).unwrap();
        assert_eq!(f.control_delay(), Duration::from_millis(2000));
        let f = Faults::parse(Some("clock-delay=600")).unwrap();
        assert_eq!(f.clock().delay, Duration::from_micros(600));
        assert_eq!(f.control_delay(), Duration::ZERO);
        let e = Faults::parse(Some("control-delay=2s")).err().expect("2s is refused").to_string();
        assert!(e.contains("\"control-delay=2s\"") && e.contains("\"2s\""), "{e}");
        let e = Faults::parse(Some("drop=-1")).err().expect("-1 is refused").to_string();
        assert!(e.contains("\"-1\" is not a whole number"), "{e}");
    }

    #[test]
    fn the_source_clock_is_moved_skewed_and_its_wall_clock_stepped() {
        let f =
            Faults::parse(Some("clock-offset=-2000,clock-skew=50,realtime-step=1500:10,clock-jitter=200"))
                .unwrap();
        let c = f.clock();
        assert_eq!(c.jitter, Duration::from_micros(200));
        let o = c.source.origin_ns;
        // At the origin: the offset only; 100 s later 50 ppm of it on top (5 ms).
        assert_eq!(c.source.mono(o), o - 2_000_000);
        assert_eq!(c.source.mono(o + 100_000_000_000), o + 100_000_000_000 - 2_000_000 + 5_000_000);
        // The wall clock: unchanged before 10 s, 1.5 s later from then on; 0 (none) stays 0.
        assert_eq!(c.source.realtime(7, o + 9_999_999_999), 7);
        assert_eq!(c.source.realtime(7, o + 10_000_000_000), 7 + 1_500_000_000);
        assert_eq!(c.source.realtime(0, o + 20_000_000_000), 0);
        // The default is the real clock.
        let d = SourceClock::default();
        assert_eq!((d.mono(123), d.realtime(5, 1 << 62)), (123, 5));
        // Jitter stays within its range and varies.
        let state = AtomicU64::new(1);
        let v: Vec<Duration> = (0..1000).map(|_| jitter(&state, c.jitter)).collect();
        assert!(v.iter().all(|d| *d <= c.jitter));
        assert!(
            v.iter().any(|d| *d < Duration::from_micros(50))
                && v.iter().any(|d| *d > Duration::from_micros(150))
        );
        for bad in
            ["clock-skew=2000", "clock-skew=1.5", "realtime-step=5", "realtime-step=a:1", "clock-offset=x"]
        {
            let e = Faults::parse(Some(bad)).err().unwrap_or_else(|| panic!("{bad} accepted")).to_string();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }
}
