//! `sim:field`: a simulated sound card with its own clock, sampling one analytic sound field
//! shared by every sim card of the process (ground truth for several-device acquisitions,
//! docs/multi-device.md).
//!
//! `sim:field?ppm=87&slew=0.5&jitter_us=200&seed=1&offset_us=3130&ch=2&xrun_at_s=8&unplug_at_s=10&replug_at_s=12`
//! (every parameter optional):
//!
//! - the card's clock runs `ppm` off nominal, slewing `slew` ppm/s ([`align::sim::Clock`]);
//!   its frame 0 is at a whole second of CLOCK_MONOTONIC plus `offset_us`. The field is
//!   [`align::sim::Field::standard`], integer tones only: it repeats every second, so the
//!   value of any card's frame `n` is `field(ch + c, frac(offset + clock.instant(n)))`, known
//!   to a checker from the frame index alone;
//! - the card is paced by its clock: a read of frames `a..b` sleeps until frame `b` is due on
//!   it, plus a wake-up jitter uniform in `0..jitter_us` (seeded by `seed`); its stamp is the
//!   first frame's true instant plus that jitter, as a device timestamp with its interrupt
//!   latency would be: how late the thread really woke (a loaded machine) delays the
//!   delivery, and marks a read later than its own duration `late`, but not the stamp, so
//!   the stamps' noise is what the URL says and a run is reproducible;
//! - `ch`: the field channel of the card's first channel;
//! - `xrun_at_s`: once, that many seconds after the first start, the card loses 50 ms of
//!   frames and reports an overrun; `unplug_at_s`: from then the card fails (ENODEV-like),
//!   and [`Capture::reopen`] fails until `replug_at_s` (never, without it), when the card
//!   starts again at the next whole second (its frames from 0 again, same clock).

use align::sim::{Clock, Field, Rng, FULL_SCALE};
use bassport::format::error_code;
use bassport::sys::monotonic_ns;

use super::{sleep_until, Capture, ReadEvent, StopSignal};

/// The parameters of a `sim:field` card, checked.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FieldParams {
    /// Clock offset from nominal, ppm.
    pub ppm: f64,
    /// Clock slew, ppm/s.
    pub slew: f64,
    /// Largest extra wake-up delay, µs.
    pub jitter_us: f64,
    /// Seed of the jitter.
    pub seed: u64,
    /// Frame 0 after the whole second, µs.
    pub offset_us: f64,
    /// Field channel of the first channel.
    pub ch: u32,
    /// One overrun at this time after the first start, s.
    pub xrun_at_s: Option<f64>,
    /// Unplugged at this time after the first start, s.
    pub unplug_at_s: Option<f64>,
    /// Reopens succeed from this time after the first start, s.
    pub replug_at_s: Option<f64>,
}

impl Eq for FieldParams {}

/// Parses what follows `sim:field` (`""` or `?k=v&k=v`), naming a bad key or value.
pub fn parse(rest: &str) -> Result<FieldParams, String> {
    let mut p = FieldParams::default();
    let query = match rest {
        "" => return Ok(p),
        r => r.strip_prefix('?').ok_or_else(|| {
            format!("sim:field{rest}: parameters follow a '?', e.g. sim:field?ppm=87&seed=1")
        })?,
    };
    for pair in query.split('&') {
        let (k, v) =
            pair.split_once('=').ok_or_else(|| format!("sim:field parameter {pair:?} is not KEY=VALUE"))?;
        let num = |lo: f64, hi: f64| -> Result<f64, String> {
            let x: f64 = v.parse().map_err(|_| format!("sim:field {k}={v:?} is not a number"))?;
            if !(lo..=hi).contains(&x) {
                return Err(format!("sim:field {k}={v} is out of range ({lo} to {hi})"));
            }
            Ok(x)
        };
        match k {
            "ppm" => p.ppm = num(-10_000.0, 10_000.0)?,
            "slew" => p.slew = num(-100.0, 100.0)?,
            "jitter_us" => p.jitter_us = num(0.0, 100_000.0)?,
            "offset_us" => p.offset_us = num(0.0, 999_999.0)?,
            "seed" => {
                p.seed = v.parse().map_err(|_| format!("sim:field seed={v:?} is not an unsigned integer"))?
            }
            "ch" => p.ch = num(0.0, 1024.0)? as u32,
            "xrun_at_s" => p.xrun_at_s = Some(num(0.0, 1e6)?),
            "unplug_at_s" => p.unplug_at_s = Some(num(0.0, 1e6)?),
            "replug_at_s" => p.replug_at_s = Some(num(0.0, 1e6)?),
            _ => {
                return Err(format!(
                    "sim:field has no parameter {k:?} (ppm, slew, jitter_us, seed, offset_us, ch, \
                     xrun_at_s, unplug_at_s, replug_at_s)"
                ))
            }
        }
    }
    if let (Some(r), u) = (p.replug_at_s, p.unplug_at_s) {
        if !u.is_some_and(|u| r > u) {
            return Err(format!("sim:field replug_at_s={r} needs an earlier unplug_at_s"));
        }
    }
    Ok(p)
}

/// A running `sim:field` card.
pub struct FieldDevice {
    p: FieldParams,
    rate: f64,
    channels: usize,
    period: usize,
    field: Field,
    clock: Clock,
    rng: Rng,
    /// CLOCK_MONOTONIC (ns) of the whole second the current run's frame 0 follows.
    second_ns: u64,
    /// Of the first start (the times of the injected events count from it).
    first_start_ns: Option<u64>,
    /// Frames produced or lost in this run.
    pos: u64,
    xrun_done: bool,
    unplugged: bool,
}

const NS: f64 = 1e9;

impl FieldDevice {
    /// A card of `p` at `rate` Hz with `channels` channels, reading `period` frames at most.
    pub fn new(p: FieldParams, rate: u32, channels: u32, period: u32) -> FieldDevice {
        let rate = f64::from(rate.max(1));
        let clock =
            Clock { nominal_hz: rate, ppm: p.ppm, slew_ppm_per_s: p.slew, start_s: p.offset_us * 1e-6 };
        FieldDevice {
            rng: Rng::new(p.seed),
            p,
            rate,
            channels: channels as usize,
            period: period.max(1) as usize,
            field: Field::standard(),
            clock,
            second_ns: 0,
            first_start_ns: None,
            pos: 0,
            xrun_done: false,
            unplugged: false,
        }
    }

    /// CLOCK_MONOTONIC (ns) at which frame `n` of this run is (truly) sampled.
    fn instant_ns(&self, n: u64) -> u64 {
        self.second_ns + (self.clock.instant(n as f64) * NS).round() as u64
    }

    /// Seconds since the first start.
    fn age_s(&self, now: u64) -> f64 {
        self.first_start_ns.map_or(0.0, |s| now.saturating_sub(s) as f64 / NS)
    }

    fn fill(&self, out: &mut [i32], first: u64, frames: usize) {
        let ch = self.channels;
        for (i, frame) in out[..frames * ch].chunks_exact_mut(ch).enumerate() {
            // The field repeats every second: its time is the instant's fraction of a second.
            let t = self.clock.instant((first + i as u64) as f64).fract();
            for (c, s) in frame.iter_mut().enumerate() {
                let v = self.field.value(self.p.ch as usize + c, t);
                *s = (v * FULL_SCALE).round().clamp(i32::MIN as f64, i32::MAX as f64) as i32;
            }
        }
    }
}

impl Capture for FieldDevice {
    fn start(&mut self) -> Result<(), String> {
        let now = monotonic_ns();
        self.first_start_ns.get_or_insert(now);
        self.second_ns = now.div_ceil(1_000_000_000) * 1_000_000_000;
        self.pos = 0;
        Ok(())
    }

    fn reopen(&mut self) -> Option<Result<(), String>> {
        let age = self.age_s(monotonic_ns());
        Some(match self.p.replug_at_s {
            Some(r) if age >= r => {
                self.unplugged = false;
                self.start()
            }
            _ => Err(format!("sim:field: unplugged (simulated), {age:.1} s after the start")),
        })
    }

    fn read(&mut self, out: &mut [i32], max_frames: usize, stop: &StopSignal) -> ReadEvent {
        let age = self.age_s(monotonic_ns());
        let replugged = self.p.replug_at_s.is_some_and(|r| age >= r);
        if self.unplugged || self.p.unplug_at_s.is_some_and(|u| age >= u && !replugged) {
            self.unplugged = true;
            return ReadEvent::Failed {
                code: error_code::DEVICE_LOST,
                message: "sim:field: device unplugged (simulated ENODEV)".into(),
            };
        }
        if !self.xrun_done && self.p.xrun_at_s.is_some_and(|x| age >= x) {
            self.xrun_done = true;
            self.pos += (self.rate / 20.0) as u64;
            return ReadEvent::Xrun;
        }
        let n = max_frames.min(self.period).min(out.len() / self.channels.max(1));
        let first = self.pos;
        let jitter = (self.rng.next_f64() * self.p.jitter_us * 1e3) as u64;
        let due = self.instant_ns(first + n as u64);
        if !sleep_until(due + jitter, stop) {
            return ReadEvent::Stopped;
        }
        let woke = monotonic_ns();
        self.fill(out, first, n);
        self.pos += n as u64;
        let stamp = self.instant_ns(first) + jitter;
        ReadEvent::Frames {
            frames: n,
            first_mono_ns: stamp,
            time_estimated: false,
            observed_mono_ns: stamp,
            late: woke.saturating_sub(due) > (due - self.instant_ns(first)).max(super::sim::LATE_NS),
        }
    }

    fn format_name(&self) -> &'static str {
        "S32_LE"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameters_parse_and_bad_ones_are_named() {
        let p = parse("?ppm=87&slew=0.5&jitter_us=200&seed=1&unplug_at_s=10&replug_at_s=12").unwrap();
        assert_eq!((p.ppm, p.slew, p.jitter_us, p.seed), (87.0, 0.5, 200.0, 1));
        assert_eq!((p.unplug_at_s, p.replug_at_s), (Some(10.0), Some(12.0)));
        assert_eq!(parse("").unwrap(), FieldParams::default());
        for (bad, want) in [
            ("?ppm=fast", "ppm=\"fast\""),
            ("?ppm=20000", "ppm=20000 is out of range"),
            ("?volume=3", "no parameter \"volume\""),
            ("?ppm", "\"ppm\" is not KEY=VALUE"),
            ("ppm=1", "follow a '?'"),
            ("?replug_at_s=3", "replug_at_s=3 needs an earlier unplug_at_s"),
            ("?unplug_at_s=5&replug_at_s=3", "replug_at_s=3"),
            ("?seed=-1", "seed=\"-1\""),
        ] {
            let e = parse(bad).unwrap_err();
            assert!(e.contains(want), "{bad}: {e}");
        }
    }

    #[test]
    fn samples_are_the_field_at_the_cards_true_instants() {
        let p = parse("?ppm=-143&offset_us=3130&ch=1").unwrap();
        let mut d = FieldDevice::new(p, 48_000, 2, 480);
        d.start().unwrap();
        let mut out = vec![0; 960];
        d.fill(&mut out, 48_000, 480);
        let field = Field::standard();
        let t: f64 = 3130e-6 + 48_000.0 / 48_000.0 / (1.0 - 143e-6);
        let want = (field.value(2, t.fract()) * FULL_SCALE).round() as i32;
        assert!((out[1] - want).abs() < 2, "{} vs {want}", out[1]);
    }
}
