//! Deterministic fault injection for the network tests, reachable only from the test binary
//! `bass-bridge-faults` (`--fault drop=S,dup=S,reorder=S,delay=S serve ...`): drops, duplicates, swaps with the next
//! message, or holds back by four messages the message of sequence number S;
//! `control-delay=MS` holds every forwarded control request MS milliseconds before it goes to
//! the broker (to have many in progress at once); `clock-delay=US` holds every clock answer US
//! microseconds after its time was read (an asymmetric path: the answer's way back is longer
//! than the probe's way out, the case a round trip's half cannot see). The installed
//! `bass-bridge` has no such option.

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
    clock_delay: Duration,
}

impl Faults {
    /// Parses `--fault`.
    pub fn parse(spec: Option<&str>) -> Result<Faults> {
        let Some(spec) = spec else { return Ok(Faults::default()) };
        let mut plan = Vec::new();
        let mut control_delay = Duration::ZERO;
        let mut clock_delay = Duration::ZERO;
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
            if what == "clock-delay" {
                clock_delay = Duration::from_micros(number()?);
                continue;
            }
            let a = match what {
                "drop" => Action::Drop,
                "dup" => Action::Dup,
                "reorder" => Action::Reorder,
                "delay" => Action::Delay,
                _ => bail!(
                    "--fault: unknown fault {what:?} (drop, dup, reorder, delay, control-delay, clock-delay)"
                ),
            };
            plan.push((number()?, a));
        }
        Ok(Faults { plan, held: Vec::new(), control_delay, clock_delay })
    }

    /// How long each clock answer is held after its time was read (`clock-delay=US`).
    pub fn clock_delay(&self) -> Duration {
        self.clock_delay
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
        assert_eq!(f.clock_delay(), Duration::from_micros(600));
        assert_eq!(f.control_delay(), Duration::ZERO);
        let e = Faults::parse(Some("control-delay=2s")).err().expect("2s is refused").to_string();
        assert!(e.contains("\"control-delay=2s\"") && e.contains("\"2s\""), "{e}");
        let e = Faults::parse(Some("drop=-1")).err().expect("-1 is refused").to_string();
        assert!(e.contains("\"-1\" is not a whole number"), "{e}");
    }
}
