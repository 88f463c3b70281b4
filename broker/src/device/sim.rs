//! Simulated capture devices (`sim:NAME`), paced in real time with absolute-deadline sleeps
//! (`clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)` on a thread without timer slack, see
//! [`super::precise_timers`]), any rate, chunk size and channel
//! count. Their content is deterministic:
//!
//! - `sim:pattern` — `basskit::testsignal::pattern_sample(frame, channel)`: every sample
//!   names its device frame and channel;
//! - `sim:sine` — a 440 Hz tone on channel 0, 660 Hz on channel 1 (then 880, 1100, ... Hz),
//!   at half full scale;
//! - `sim:silence` — zeros;
//! - `sim:xrun` — the pattern, but after every `rate/2` frames the device loses
//!   `rate/20 + 7` frames and reports an overrun (tests the gap filling);
//! - `sim:stall` — the pattern for `rate/2` frames, then nothing, without an error (tests
//!   the stall watchdog);
//! - `sim:unplug` — the pattern for `rate/2` frames, then a fatal ENODEV-like error;
//! - `sim:latestamps` — the pattern, paced as usual, but the times the rate estimator is
//!   given are made up, deterministically, as a starved capture thread would see them: a
//!   latency of 50..149 µs, a catch-up burst every 100 ms (the frames due in 8 ms seen
//!   together at its end) and a 500 ms stall every 4 s (seen together at its end). A
//!   late-stamp injector that does not depend on the machine's load (tests the estimator).
//!
//! Device frame `k` (from 1) is due at `start + k / rate`; a read of `n` frames sleeps until
//! the last of them is due. Chunk timestamps are the exact due times; the rate estimator
//! gets the observed wake-up times instead, so it measures what it would on a real device.
//! A device that falls behind (its thread starved or stopped) delivers the frames it owes in
//! a burst; a read that returns more than a read's duration (at least [`LATE_NS`]) after its
//! last frame was due is marked `late`, and its chunk is flagged `LATE`.

use basskit::testsignal::pattern_sample;
use bassport::format::error_code;
use bassport::sys::monotonic_ns;

use super::{sleep_until, Capture, ReadEvent, StopSignal};

/// The simulated devices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimKind {
    /// The test pattern.
    Pattern,
    /// Distinct sine tones per channel.
    Sine,
    /// Zeros.
    Silence,
    /// The pattern with periodic overruns.
    Xrun,
    /// The pattern, then silence without error.
    Stall,
    /// The pattern, then a fatal error.
    Unplug,
    /// The pattern, with injected late stamps for the rate estimator.
    LateStamps,
}

/// Names and descriptions, as listed by ListDevices.
pub const DEVICES: [(SimKind, &str); 7] = [
    (SimKind::Pattern, "Simulated: test pattern (each sample encodes its frame index and channel)"),
    (SimKind::Sine, "Simulated: sine tones, 440 Hz left, 660 Hz right"),
    (SimKind::Silence, "Simulated: silence"),
    (SimKind::Xrun, "Simulated: test pattern with an overrun every half second"),
    (SimKind::Stall, "Simulated: test pattern for half a second, then stops delivering (stall)"),
    (SimKind::Unplug, "Simulated: test pattern for half a second, then unplugged (ENODEV)"),
    (SimKind::LateStamps, "Simulated: test pattern, rate estimator fed injected late timestamps"),
];

impl SimKind {
    /// The name after `sim:`.
    pub fn name(self) -> &'static str {
        match self {
            SimKind::Pattern => "pattern",
            SimKind::Sine => "sine",
            SimKind::Silence => "silence",
            SimKind::Xrun => "xrun",
            SimKind::Stall => "stall",
            SimKind::Unplug => "unplug",
            SimKind::LateStamps => "latestamps",
        }
    }

    /// Parses the name after `sim:`.
    pub fn from_name(name: &str) -> Option<SimKind> {
        DEVICES.iter().map(|(k, _)| *k).find(|k| k.name() == name)
    }
}

const NS_PER_MS: u64 = 1_000_000;
/// A read delivered later than this after its last frame was due (or later than the read's
/// own duration, if longer) is a catch-up read.
pub const LATE_NS: u64 = NS_PER_MS;
/// How long a stalled `sim:stall` waits per read before reporting "no data".
const STALL_SLICE_NS: u64 = 100 * NS_PER_MS;

/// A running simulated device.
pub struct SimDevice {
    kind: SimKind,
    rate: u64,
    channels: usize,
    period: usize,
    start_ns: u64,
    /// Device frames produced or lost so far (the next frame is `pos + 1`).
    pos: u64,
    /// Device frames delivered since the last event (for the periodic events).
    since_event: u64,
    pending_xrun: bool,
}

impl SimDevice {
    /// A device of `kind` at `rate` Hz with `channels` channels, reading `period` frames at most.
    pub fn new(kind: SimKind, rate: u32, channels: u32, period: u32) -> SimDevice {
        SimDevice {
            kind,
            rate: u64::from(rate.max(1)),
            channels: channels as usize,
            period: period.max(1) as usize,
            start_ns: 0,
            pos: 0,
            since_event: 0,
            pending_xrun: false,
        }
    }

    /// CLOCK_MONOTONIC (ns) at which device frame `k` (from 1; 0 = start) is due.
    fn due_ns(&self, k: u64) -> u64 {
        self.start_ns + (u128::from(k) * 1_000_000_000 / u128::from(self.rate)) as u64
    }

    fn event_every(&self) -> u64 {
        (self.rate / 2).max(1)
    }

    /// Writes frames `first..first + frames` of the device's signal into `out`.
    fn fill(&self, out: &mut [i32], first: u64, frames: usize) {
        let ch = self.channels;
        for (i, frame) in out[..frames * ch].chunks_exact_mut(ch).enumerate() {
            let k = first + i as u64;
            for (c, s) in frame.iter_mut().enumerate() {
                *s = match self.kind {
                    SimKind::Silence => 0,
                    SimKind::Sine => sine_sample(k, c as u32, self.rate),
                    _ => pattern_sample(k, c as u32),
                };
            }
        }
    }
}

/// For `sim:latestamps`: when a starved thread would see a read whose last frame is due
/// `due_ns` after the start (read number `k`), in ns after the start.
pub fn injected_seen_ns(due_ns: u64, k: u64) -> u64 {
    const BURST_EVERY: u64 = 100 * NS_PER_MS;
    const BURST: u64 = 8 * NS_PER_MS;
    const STALL_EVERY: u64 = 4_000 * NS_PER_MS;
    const STALL_AT: u64 = 2_000 * NS_PER_MS;
    const STALL: u64 = 500 * NS_PER_MS;
    let latency = 50_000 + k.wrapping_mul(7919) % 100 * 1_000;
    let in_stall = due_ns % STALL_EVERY;
    let seen = if (STALL_AT..STALL_AT + STALL).contains(&in_stall) {
        due_ns - in_stall + STALL_AT + STALL
    } else if due_ns % BURST_EVERY < BURST {
        due_ns - due_ns % BURST_EVERY + BURST
    } else {
        due_ns
    };
    seen + latency
}

/// Sample of `sim:sine`: (440 + 220 c) Hz at half full scale, phase 0 at frame 0.
pub fn sine_sample(frame: u64, channel: u32, rate: u64) -> i32 {
    let f = 440.0 + 220.0 * f64::from(channel);
    // Reduce the phase in integers first so that it stays exact for long runs.
    let cycles = (frame as u128 * (f as u128)) % u128::from(rate);
    let phase = 2.0 * std::f64::consts::PI * cycles as f64 / rate as f64;
    (phase.sin() * f64::from(1u32 << 30)).round() as i32
}

impl Capture for SimDevice {
    fn start(&mut self) -> Result<(), String> {
        self.start_ns = monotonic_ns();
        Ok(())
    }

    fn read(&mut self, out: &mut [i32], max_frames: usize, stop: &StopSignal) -> ReadEvent {
        if self.pending_xrun {
            self.pending_xrun = false;
            self.pos += self.rate / 20 + 7;
            return ReadEvent::Xrun;
        }
        let every = self.event_every();
        let ends = matches!(self.kind, SimKind::Stall | SimKind::Unplug);
        if ends && self.since_event >= every {
            if self.kind == SimKind::Unplug {
                return ReadEvent::Failed {
                    code: error_code::DEVICE_LOST,
                    message: "sim:unplug: device unplugged (simulated ENODEV)".into(),
                };
            }
            // Stalled: deliver nothing until stopped.
            let _ = sleep_until(monotonic_ns() + STALL_SLICE_NS, stop);
            return if stop.is_set() { ReadEvent::Stopped } else { ReadEvent::Idle };
        }
        let mut n = max_frames.min(self.period).min(out.len() / self.channels.max(1));
        if matches!(self.kind, SimKind::Xrun | SimKind::Stall | SimKind::Unplug) {
            n = n.min((every - self.since_event) as usize);
        }
        let first = self.pos + 1;
        let due = self.due_ns(self.pos + n as u64);
        if !sleep_until(due, stop) {
            return ReadEvent::Stopped;
        }
        let woke = monotonic_ns();
        self.fill(out, first, n);
        let span = due - self.due_ns(self.pos);
        let late = woke.saturating_sub(due) > span.max(LATE_NS);
        let observed = if self.kind == SimKind::LateStamps {
            let reads = self.pos / self.period as u64;
            self.start_ns + injected_seen_ns(due - self.start_ns, reads)
        } else {
            woke
        };
        self.pos += n as u64;
        self.since_event += n as u64;
        if self.kind == SimKind::Xrun && self.since_event >= every {
            self.since_event = 0;
            self.pending_xrun = true;
        }
        ReadEvent::Frames {
            frames: n,
            first_mono_ns: self.due_ns(first - 1),
            time_estimated: false,
            observed_mono_ns: observed.saturating_sub(span),
            late,
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
    fn sine_channels_have_distinct_tones_at_half_scale() {
        let rate = 48_000;
        let peak = |c| (0..rate).map(|k| sine_sample(k, c, rate).unsigned_abs()).max().unwrap();
        assert!((peak(0) as i64 - (1 << 30)).abs() < 1 << 16);
        // 440 Hz repeats every rate/gcd(rate, 440) frames = 1200; 660 Hz every 800.
        assert_eq!(sine_sample(1200, 0, rate), sine_sample(0, 0, rate));
        assert_eq!(sine_sample(800, 1, rate), sine_sample(0, 1, rate));
        assert_ne!(sine_sample(100, 0, rate), sine_sample(100, 1, rate));
    }

    #[test]
    fn names_round_trip() {
        for (k, _) in DEVICES {
            assert_eq!(SimKind::from_name(k.name()), Some(k));
        }
        assert_eq!(SimKind::from_name("nope"), None);
    }
}
