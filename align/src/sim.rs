//! The ground truth: simulated sound cards sampling one analytic sound field.
//!
//! A [`Clock`] gives each frame of a card its true instant (seconds of simulation time):
//! the card runs at `nominal_hz * (1 + ppm*1e-6 + slew*1e-6*u)`, `u` the time since its
//! frame 0, which is at `start_s`. A [`Field`] is a sum of tones per channel, evaluated at
//! any true time, so the aligned follower channel has an exact expected value at every
//! master frame: `field.value(ch, master.instant(k))`. A [`SimCard`] samples the field at
//! its own true instants (left-justified S32, as bass ports carry) and stamps each chunk
//! with the CLOCK_MONOTONIC time its capture thread sees: the true instant of the chunk's
//! first frame plus a wake-up delay (jitter is on the stamps only, never on the samples).
//! Everything is deterministic for a given seed.

use crate::Chunk;

/// Offset of simulation time 0 on the simulated CLOCK_MONOTONIC, in seconds.
pub const MONOTONIC_ORIGIN_S: f64 = 1000.0;

/// One tone of the field: `amplitude * sin(2*pi*hz*t + phase + channel*channel_phase)`.
#[derive(Clone, Copy, Debug)]
pub struct Tone {
    /// Frequency in Hz.
    pub hz: f64,
    /// Amplitude (full scale is 1).
    pub amplitude: f64,
    /// Phase at t = 0 of channel 0, radians.
    pub phase: f64,
    /// Phase added per channel index, radians.
    pub channel_phase: f64,
}

/// The analytic sound field shared by every card.
#[derive(Clone, Debug)]
pub struct Field {
    /// The tones; the first two are the pilots.
    pub tones: Vec<Tone>,
}

impl Field {
    /// Pilots at 997 Hz and 3 kHz plus five broadband tones (211 Hz to 15.1 kHz), peak
    /// below 0.9 of full scale.
    pub fn standard() -> Field {
        let t = |hz, amplitude, phase, channel_phase| Tone { hz, amplitude, phase, channel_phase };
        Field {
            tones: vec![
                t(997.0, 0.25, 0.3, 0.7),
                t(3000.0, 0.2, 1.1, 1.9),
                t(211.0, 0.12, 2.0, 0.4),
                t(1723.0, 0.1, 0.5, 2.6),
                t(5417.0, 0.08, 4.0, 1.2),
                t(9001.0, 0.06, 3.3, 0.9),
                t(15101.0, 0.04, 5.1, 2.2),
            ],
        }
    }

    /// The pilot tones (the first two).
    pub fn pilots(&self) -> &[Tone] {
        &self.tones[..2.min(self.tones.len())]
    }

    /// The field of channel `ch` at true time `t` (seconds), full scale 1.
    pub fn value(&self, ch: usize, t: f64) -> f64 {
        self.tones
            .iter()
            .map(|tone| {
                let ph = std::f64::consts::TAU * tone.hz * t + tone.phase + ch as f64 * tone.channel_phase;
                tone.amplitude * ph.sin()
            })
            .sum()
    }

    /// The largest slope of any channel, in full scale per second (a bound: the sum of
    /// the tones' amplitude times angular frequency).
    pub fn max_slope(&self) -> f64 {
        self.tones.iter().map(|t| t.amplitude * std::f64::consts::TAU * t.hz).sum()
    }
}

/// Full scale of a left-justified S32 sample.
pub const FULL_SCALE: f64 = 2_147_483_648.0;

/// A full-scale-1 value as a left-justified S32 sample (rounded, clamped).
pub fn to_s32(v: f64) -> i32 {
    (v * FULL_SCALE).round().clamp(i32::MIN as f64, i32::MAX as f64) as i32
}

/// A card's clock: the true instant of each of its frames.
#[derive(Clone, Copy, Debug)]
pub struct Clock {
    /// Nominal rate, Hz.
    pub nominal_hz: f64,
    /// Rate offset from nominal at frame 0, ppm.
    pub ppm: f64,
    /// Rate change per second, ppm/s.
    pub slew_ppm_per_s: f64,
    /// True time of frame 0, seconds.
    pub start_s: f64,
}

impl Clock {
    /// The true instant of (fractional) frame `n`, seconds.
    pub fn instant(&self, n: f64) -> f64 {
        let (b, s) = (1.0 + self.ppm * 1e-6, self.slew_ppm_per_s * 1e-6);
        // n/fs = b*u + s/2*u^2, solved for u in the form that is exact for s = 0.
        let c = n / self.nominal_hz;
        let disc = (b * b + 2.0 * s * c).max(0.0);
        self.start_s + 2.0 * c / (b + disc.sqrt())
    }

    /// The (fractional) frame at true time `t`.
    pub fn frame_at(&self, t: f64) -> f64 {
        let u = t - self.start_s;
        self.nominal_hz * ((1.0 + self.ppm * 1e-6) * u + 0.5 * self.slew_ppm_per_s * 1e-6 * u * u)
    }
}

/// The wake-up delay of a capture thread: `min_s` plus a uniform part up to `max_s`, and
/// with probability `late_probability` per chunk a late stamp up to `late_max_s` more.
#[derive(Clone, Copy, Debug)]
pub struct Jitter {
    /// Smallest delay, seconds.
    pub min_s: f64,
    /// Largest ordinary delay, seconds.
    pub max_s: f64,
    /// Probability of a late stamp per chunk.
    pub late_probability: f64,
    /// Largest extra delay of a late stamp, seconds.
    pub late_max_s: f64,
}

impl Jitter {
    /// 50 to 200 µs, no late stamps.
    pub fn typical() -> Jitter {
        Jitter { min_s: 50e-6, max_s: 200e-6, late_probability: 0.0, late_max_s: 0.0 }
    }
}

/// Deterministic pseudo-random numbers in [0, 1) (splitmix64).
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator for `seed`.
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    /// The next number in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A chunk a simulated card delivered, with its ground truth.
#[derive(Clone, Debug)]
pub struct SimChunk {
    /// Interleaved samples.
    pub samples: Vec<i32>,
    /// Frames in the chunk.
    pub frames: usize,
    /// Observed CLOCK_MONOTONIC stamp of the first frame, ns (true instant plus delay).
    pub stamp_ns: u64,
    /// The card's index of the first frame (ground truth; the aligner is not told).
    pub first_frame: u64,
    /// Frames were lost just before this chunk (a marked gap).
    pub after_gap: bool,
}

impl SimChunk {
    /// The chunk as the aligner takes it.
    pub fn as_chunk(&self) -> Chunk<'_> {
        Chunk {
            samples: &self.samples,
            frames: self.frames,
            stamp_ns: self.stamp_ns,
            after_gap: self.after_gap,
        }
    }
}

/// A simulated sound card.
#[derive(Clone, Debug)]
pub struct SimCard {
    /// The card's clock.
    pub clock: Clock,
    /// Channels per frame.
    pub channels: usize,
    /// Frames per chunk.
    pub chunk_frames: usize,
    /// The capture thread's wake-up delay.
    pub jitter: Jitter,
    /// Lost frame ranges `[start, end)`, whole chunks; the first chunk after each is
    /// marked `after_gap` when `mark_gaps` is set.
    pub gaps: Vec<(u64, u64)>,
    /// Whether chunks after a gap carry the `after_gap` mark.
    pub mark_gaps: bool,
    /// Channel index of the card's first channel in the field.
    pub first_field_channel: usize,
    next_frame: u64,
    rng: Rng,
}

impl SimCard {
    /// A card with `clock`, `channels` (field channels from 0), `chunk_frames`, `jitter`.
    pub fn new(clock: Clock, channels: usize, chunk_frames: usize, jitter: Jitter, seed: u64) -> SimCard {
        SimCard {
            clock,
            channels,
            chunk_frames,
            jitter,
            gaps: Vec::new(),
            mark_gaps: true,
            first_field_channel: 0,
            next_frame: 0,
            rng: Rng::new(seed),
        }
    }

    /// The true instant of the first frame of the next chunk the card will deliver.
    pub fn next_instant(&self) -> f64 {
        self.clock.instant(self.next_frame as f64)
    }

    fn in_gap(&self, frame: u64) -> bool {
        self.gaps.iter().any(|&(a, b)| frame >= a && frame < b)
    }

    /// The next delivered chunk, sampled from `field` (chunks inside a gap are skipped).
    pub fn next_chunk(&mut self, field: &Field) -> SimChunk {
        let mut after_gap = false;
        while self.in_gap(self.next_frame) {
            self.next_frame += self.chunk_frames as u64;
            after_gap = self.mark_gaps;
        }
        let first = self.next_frame;
        self.next_frame += self.chunk_frames as u64;
        let mut samples = Vec::with_capacity(self.chunk_frames * self.channels);
        for f in 0..self.chunk_frames {
            let t = self.clock.instant((first + f as u64) as f64);
            for ch in 0..self.channels {
                samples.push(to_s32(field.value(self.first_field_channel + ch, t)));
            }
        }
        let j = self.jitter;
        let mut delay = j.min_s + self.rng.next_f64() * (j.max_s - j.min_s);
        if self.rng.next_f64() < j.late_probability {
            delay += self.rng.next_f64() * j.late_max_s;
        }
        let seen = MONOTONIC_ORIGIN_S + self.clock.instant(first as f64) + delay;
        SimChunk {
            samples,
            frames: self.chunk_frames,
            stamp_ns: (seen * 1e9).round() as u64,
            first_frame: first,
            after_gap,
        }
    }
}

/// Which card a [`Rig`] event comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    /// The master card.
    Master,
    /// Follower `i`.
    Follower(usize),
}

/// A master and followers sampling one field, delivering chunks in the order their
/// capture threads see them (by observed stamp).
#[derive(Clone, Debug)]
pub struct Rig {
    /// The shared field.
    pub field: Field,
    /// The master card.
    pub master: SimCard,
    /// The follower cards.
    pub followers: Vec<SimCard>,
}

impl Rig {
    /// The standard scenario: 48 kHz, 480-frame chunks, stereo; the master at nominal
    /// rate starting at 0 s, one follower `ppm` off slewing `slew_ppm_per_s`, starting
    /// 3.13 ms later (a fractional sample offset); 50–200 µs of wake-up jitter on both.
    pub fn standard(ppm: f64, slew_ppm_per_s: f64, seed: u64) -> Rig {
        let clock =
            |ppm, slew_ppm_per_s, start_s| Clock { nominal_hz: 48_000.0, ppm, slew_ppm_per_s, start_s };
        Rig {
            field: Field::standard(),
            master: SimCard::new(clock(0.0, 0.0, 0.0), 2, 480, Jitter::typical(), seed),
            followers: vec![SimCard::new(
                clock(ppm, slew_ppm_per_s, 3.13e-3),
                2,
                480,
                Jitter::typical(),
                seed.wrapping_mul(31).wrapping_add(7),
            )],
        }
    }

    /// The next chunk in arrival order: the card whose next chunk is due first.
    pub fn next_event(&mut self) -> (Source, SimChunk) {
        let mut best = (Source::Master, self.master.next_instant());
        for (i, f) in self.followers.iter().enumerate() {
            let due = f.next_instant();
            if due < best.1 {
                best = (Source::Follower(i), due);
            }
        }
        let chunk = match best.0 {
            Source::Master => self.master.next_chunk(&self.field),
            Source::Follower(i) => self.followers[i].next_chunk(&self.field),
        };
        (best.0, chunk)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clock_maps_frames_to_instants_and_back() {
        for slew in [0.0, 1.0] {
            let c = Clock { nominal_hz: 48_000.0, ppm: -143.0, slew_ppm_per_s: slew, start_s: 0.25 };
            for n in [0.0, 1.5, 48_000.0, 960_000.0] {
                let back = c.frame_at(c.instant(n));
                assert!((back - n).abs() < 1e-6, "frame {n} came back as {back}");
            }
        }
    }
}
