//! The sidecar of a recording, `FILE.wav.json`: one definition for the writer (`bass record`),
//! the replay (`sim:file:`) and the checker (`bass record --check`).
//!
//! WAV frame `i` (0-based) is frame `recording.first_frame + i` of the acquisition. The
//! sidecar describes exactly the frames in the file:
//!
//! - `losses`: runs of frames the recorder lost (the port overtook it), written as zeros in
//!   the WAV, each inside the file;
//! - `chunks`: one row per chunk of the acquisition overlapping the file and still on the port
//!   when the recorder read it (a chunk lost whole has no row), with its first frame (a chunk
//!   start, possibly before the file's first frame), timestamps and flags, and (port format
//!   2.4) its timestamp bound and channel masks, left out when not known or 0;
//! - `recording.gap_frames`: the frames of GAP chunks inside the file, not counting lost ones;
//! - `recording.started_after_requested`: frames between the requested first frame and the
//!   first one the port still had (`--from` an index the port had already overwritten), which
//!   are not in the file and not a loss inside it.

use std::path::{Path, PathBuf};

use bassport::format::{chunk_flags, BOUND_UNKNOWN, MAX_CHANNELS, MAX_FRAME_INDEX};
use serde::{Deserialize, Serialize};

/// Every chunk flag a row may carry.
pub const KNOWN_FLAGS: u32 =
    chunk_flags::GAP | chunk_flags::DISCONTINUITY | chunk_flags::TIME_ESTIMATED | chunk_flags::LATE;

/// Largest sidecar read (a day of 100 chunks/s is about 1 GiB of rows: record in parts).
const MAX_BYTES: u64 = 1 << 30;

/// The whole sidecar.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct Sidecar {
    /// The acquisition recorded.
    pub acquisition: Acquisition,
    /// What the file holds.
    pub recording: Recording,
    /// Frames the recorder lost (zeros in the WAV), sorted, inside the file.
    #[serde(default)]
    pub losses: Vec<Lost>,
    /// One row per chunk overlapping the file, sorted by first frame.
    #[serde(default)]
    pub chunks: Vec<ChunkRow>,
}

/// The acquisition a recording was made from.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct Acquisition {
    /// Device name.
    pub device: String,
    /// Device sample format.
    #[serde(default)]
    pub format: String,
    /// Frames per second.
    pub sample_rate: u32,
    /// Channels of the port (the file may hold a selection, see `Recording::channels`).
    pub channels: u32,
    /// Frames per chunk of the port.
    pub frames_per_chunk: u32,
    /// Chunks on the port.
    pub chunks_on_port: u32,
    /// The port's epoch.
    pub epoch: u64,
}

/// What the WAV file holds.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct Recording {
    /// The WAV file as given to `bass record`.
    pub file: String,
    /// Acquisition frame index of WAV frame 0.
    pub first_frame: u64,
    /// Frames in the file.
    pub frames: u64,
    /// `frames / sample_rate`.
    pub seconds: f64,
    /// Size of the WAV file in bytes.
    pub bytes: u64,
    /// Bits per sample in the file.
    pub bits: u16,
    /// The port channels recorded, in file order.
    pub channels: Vec<u32>,
    /// Frames of GAP chunks inside the file (not counting lost ones).
    pub gap_frames: u64,
    /// Frames the recorder lost inside the file (the sum of `losses`).
    pub lost_frames: u64,
    /// Why the recording ended.
    pub end: String,
    /// The first frame asked for (`--from`), when the port no longer had it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub requested_first_frame: Option<u64>,
    /// Frames between the requested first frame and `first_frame` (not in the file).
    #[serde(default)]
    pub started_after_requested: u64,
    /// `pcm` or `extensible` (absent in sidecars of older recorders).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wav_format: Option<String>,
    /// True in a checkpoint written while the recorder runs (it was killed if it stays so).
    #[serde(default)]
    pub in_progress: bool,
}

/// A run of frames the recorder lost.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Lost {
    /// First frame lost.
    pub first_frame: u64,
    /// Frames lost.
    pub frames: u64,
}

/// One chunk of the acquisition, as the port described it (its chunk table entry and, from
/// port format 2.4, its extension row). The bound and the masks are left out of the JSON when
/// unknown or 0, and a row without them (an older recorder's) reads as unknown and 0.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ChunkRow {
    /// First frame of the chunk (a chunk start: `(first_frame - 1) % frames_per_chunk == 0`).
    pub first_frame: u64,
    /// Frames in the chunk (the port's frames per chunk).
    pub frames: u32,
    /// CLOCK_MONOTONIC of the first frame, ns.
    pub mono_ns: u64,
    /// CLOCK_REALTIME of the first frame, ns.
    pub realtime_ns: u64,
    /// Chunk flags: 1 GAP, 2 DISCONTINUITY, 4 TIME_ESTIMATED, 8 LATE.
    pub flags: u32,
    /// Half-width (ns) of the interval around `mono_ns` (and `realtime_ns`) in which the first
    /// frame's true capture time lies; `None` (absent in the JSON) = not known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bound_ns: Option<u64>,
    /// Bit c: port channel c's frames in this chunk are zeros the device never delivered.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub missing_channels: u64,
    /// Bit c: port channel c is not yet aligned to the frame index within its bound.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub unaligned_channels: u64,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
}

impl ChunkRow {
    /// The row of a port chunk as a reader sees it.
    pub fn of(ci: &bassport::ChunkInfo) -> ChunkRow {
        ChunkRow {
            first_frame: ci.first_frame,
            frames: ci.frames,
            mono_ns: ci.mono_ns,
            realtime_ns: ci.realtime_ns,
            flags: ci.flags,
            bound_ns: ci.bound(),
            missing_channels: ci.missing_channels,
            unaligned_channels: ci.unaligned_channels,
        }
    }

    /// The bound as the port and the ROS message write it ([`BOUND_UNKNOWN`] = not known).
    pub fn bound_or_unknown(&self) -> u64 {
        self.bound_ns.unwrap_or(BOUND_UNKNOWN)
    }

    /// What is wrong with the bound and the masks of a row of a port of `channels` channels.
    pub fn ext_problems(&self, channels: u32) -> impl Iterator<Item = String> {
        let beyond = if channels >= 64 { 0 } else { !0u64 << channels };
        let mut v = Vec::new();
        if self.bound_ns == Some(BOUND_UNKNOWN) {
            v.push(format!("bound_ns {BOUND_UNKNOWN} is the port's 'not known': the row must leave it out"));
        }
        for (name, m) in
            [("missing_channels", self.missing_channels), ("unaligned_channels", self.unaligned_channels)]
        {
            if m & beyond != 0 {
                v.push(format!(
                    "{name} {m:#x} names channel {}; the port has {channels}",
                    (m & beyond).trailing_zeros()
                ));
            }
        }
        v.into_iter()
    }
}

/// `FILE.wav` → `FILE.wav.json`.
pub fn path_of(wav: &Path) -> PathBuf {
    let mut s = wav.as_os_str().to_owned();
    s.push(".json");
    PathBuf::from(s)
}

/// Frames of `a..=b` inside `c..=d` (inclusive ranges).
fn overlap(a: u64, b: u64, c: u64, d: u64) -> u64 {
    let (lo, hi) = (a.max(c), b.min(d));
    if hi >= lo {
        hi - lo + 1
    } else {
        0
    }
}

impl Sidecar {
    /// Reads and checks the sidecar of `wav`: `Ok(None)` if there is none, an error naming the
    /// file and the first problem if it is unreadable or inconsistent in itself.
    pub fn load_for(wav: &Path) -> Result<Option<Sidecar>, String> {
        let p = path_of(wav);
        let f = match std::fs::File::open(&p) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(format!("sidecar {}: {e}", p.display())),
        };
        let meta = f.metadata().map_err(|e| format!("sidecar {}: {e}", p.display()))?;
        if !meta.is_file() {
            return Err(format!("sidecar {} is not a regular file", p.display()));
        }
        if meta.len() > MAX_BYTES {
            return Err(format!(
                "sidecar {} holds {} bytes, more than the {MAX_BYTES} a sidecar may",
                p.display(),
                meta.len()
            ));
        }
        let s: Sidecar = serde_json::from_reader(std::io::BufReader::new(f))
            .map_err(|e| format!("sidecar {}: not a bass record sidecar: {e}", p.display()))?;
        let problems = s.problems();
        if let Some(first) = problems.first() {
            return Err(format!(
                "sidecar {} does not agree with itself: {first}{}",
                p.display(),
                if problems.len() > 1 {
                    format!(" (and {} more problems)", problems.len() - 1)
                } else {
                    "".into()
                }
            ));
        }
        Ok(Some(s))
    }

    /// Last acquisition frame in the file (`first_frame - 1` for an empty file).
    pub fn last_frame(&self) -> u64 {
        self.recording.first_frame + self.recording.frames - 1
    }

    /// Frames of GAP rows inside the file that are not in a loss: the definition of
    /// `recording.gap_frames`. The rows and the losses must be sorted (as `problems` checks
    /// before it asks): one walk over both, linear in their number.
    pub fn gap_frames_in_file(&self) -> u64 {
        self.gap_frames_walk().0
    }

    /// [`Sidecar::gap_frames_in_file`] and the number of loss comparisons it took (at most one
    /// per GAP row and one per loss), for the test that holds it linear.
    pub fn gap_frames_walk(&self) -> (u64, u64) {
        let (first, last) = (self.recording.first_frame, self.last_frame());
        let (mut n, mut steps, mut k) = (0, 0u64, 0usize);
        for r in self.chunks.iter().filter(|r| r.flags & chunk_flags::GAP != 0) {
            let end = r.first_frame + u64::from(r.frames) - 1;
            let (lo, hi) = (r.first_frame.max(first), end.min(last));
            let inside = overlap(r.first_frame, end, first, last);
            // Losses ending before this row end before every later row too: passed for good.
            while self.losses.get(k).is_some_and(|l| l.first_frame + l.frames - 1 < lo) {
                k += 1;
                steps += 1;
            }
            let mut lost = 0;
            for l in self.losses[k.min(self.losses.len())..].iter() {
                steps += 1;
                if l.first_frame > hi {
                    break;
                }
                lost += overlap(lo, hi, l.first_frame, l.first_frame + l.frames - 1);
            }
            n += inside.saturating_sub(lost);
        }
        (n, steps)
    }

    /// The row of the chunk holding `frame`, if the sidecar has one.
    pub fn row_of(&self, frame: u64) -> Option<&ChunkRow> {
        let i = self.chunks.partition_point(|r| r.first_frame <= frame);
        let r = self.chunks.get(i.checked_sub(1)?)?;
        (frame < r.first_frame + u64::from(r.frames)).then_some(r)
    }

    /// `" (B with a timestamp bound, at most X ns; M with missing channels)"` for the rows, or
    /// `" (none with a timestamp bound)"`: the end of a checker's summary of the rows.
    pub fn ext_summary(&self) -> String {
        let bounds: Vec<u64> = self.chunks.iter().filter_map(|r| r.bound_ns).collect();
        let missing = self.chunks.iter().filter(|r| r.missing_channels != 0).count();
        match bounds.iter().max() {
            None => format!(" (none with a timestamp bound; {missing} with missing channels)"),
            Some(m) => format!(
                " ({} with a timestamp bound, at most {m} ns; {missing} with missing channels)",
                bounds.len()
            ),
        }
    }

    /// Whether `frame` was lost by the recorder.
    pub fn is_lost(&self, frame: u64) -> bool {
        let i = self.losses.partition_point(|l| l.first_frame <= frame);
        i > 0 && frame < self.losses[i - 1].first_frame + self.losses[i - 1].frames
    }

    /// Every inconsistency of the sidecar in itself, each naming the value at fault.
    pub fn problems(&self) -> Vec<String> {
        let mut v = Vec::new();
        let (a, r) = (&self.acquisition, &self.recording);
        if a.sample_rate == 0 {
            v.push("acquisition.sample_rate is 0".into());
        }
        if a.channels == 0 || a.channels > MAX_CHANNELS {
            v.push(format!("acquisition.channels {} is not in 1..={MAX_CHANNELS}", a.channels));
        }
        if a.frames_per_chunk == 0 {
            v.push("acquisition.frames_per_chunk is 0".into());
        }
        if r.first_frame == 0 || r.first_frame > MAX_FRAME_INDEX {
            v.push(format!("recording.first_frame {} is not in 1..={MAX_FRAME_INDEX}", r.first_frame));
        }
        if r.frames > MAX_FRAME_INDEX || r.first_frame.saturating_add(r.frames) > MAX_FRAME_INDEX {
            v.push(format!("recording.frames {} passes the largest frame index", r.frames));
        }
        if !matches!(r.bits, 16 | 24 | 32) {
            v.push(format!("recording.bits {} is not 16, 24 or 32", r.bits));
        }
        if r.channels.is_empty() {
            v.push("recording.channels is empty".into());
        }
        if let Some(c) = r.channels.iter().find(|&&c| c >= a.channels) {
            v.push(format!("recording.channels names channel {c}; the port has {}", a.channels));
        }
        if let Some(q) = r.requested_first_frame {
            if q.checked_add(r.started_after_requested) != Some(r.first_frame) {
                v.push(format!(
                    "recording.requested_first_frame {q} + started_after_requested {} is not first_frame {}",
                    r.started_after_requested, r.first_frame
                ));
            }
        } else if r.started_after_requested != 0 {
            v.push(format!(
                "recording.started_after_requested is {} without a requested_first_frame",
                r.started_after_requested
            ));
        }
        if !v.is_empty() {
            return v; // the checks below rely on these
        }
        let (first, last) = (r.first_frame, self.last_frame());
        let mut prev_end = 0u64;
        for (i, l) in self.losses.iter().enumerate() {
            if l.frames == 0 || l.first_frame < first || l.first_frame.saturating_add(l.frames - 1) > last {
                v.push(format!(
                    "losses[{i}]: frames {}..={} are not inside the file (frames {first}..={last})",
                    l.first_frame,
                    l.first_frame.saturating_add(l.frames).saturating_sub(1)
                ));
            } else if l.first_frame < prev_end {
                v.push(format!(
                    "losses[{i}] (frame {}) overlaps or precedes the loss before it",
                    l.first_frame
                ));
            }
            prev_end = l.first_frame.saturating_add(l.frames);
        }
        let sum: u64 = self.losses.iter().map(|l| l.frames).fold(0, u64::saturating_add);
        if sum != r.lost_frames {
            v.push(format!("recording.lost_frames is {}; the losses sum to {sum}", r.lost_frames));
        }
        let nfpc = u64::from(a.frames_per_chunk);
        let mut prev: Option<u64> = None;
        for (i, c) in self.chunks.iter().enumerate() {
            let f = c.first_frame;
            if f == 0 || (f - 1) % nfpc != 0 {
                v.push(format!("chunks[{i}]: first_frame {f} does not start a chunk of {nfpc} frames"));
            }
            if u64::from(c.frames) != nfpc {
                v.push(format!(
                    "chunks[{i}] (frame {f}): {} frames; the port's chunks hold {nfpc}",
                    c.frames
                ));
            }
            if c.flags & !KNOWN_FLAGS != 0 {
                v.push(format!("chunks[{i}] (frame {f}): unknown flags {:#x}", c.flags & !KNOWN_FLAGS));
            }
            v.extend(c.ext_problems(a.channels).map(|p| format!("chunks[{i}] (frame {f}): {p}")));
            if overlap(f, f.saturating_add(u64::from(c.frames)).saturating_sub(1), first, last) == 0 {
                v.push(format!("chunks[{i}]: chunk {f} is outside the file (frames {first}..={last})"));
            }
            if prev.is_some_and(|p| f <= p) {
                v.push(format!("chunks[{i}]: first_frame {f} does not follow the row before it"));
            }
            prev = Some(f);
        }
        if v.is_empty() {
            let g = self.gap_frames_in_file();
            if g != r.gap_frames {
                v.push(format!(
                    "recording.gap_frames is {}; the GAP chunks hold {g} frames of the file",
                    r.gap_frames
                ));
            }
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Sidecar {
        Sidecar {
            acquisition: Acquisition {
                device: "sim:xrun".into(),
                format: "S32_LE".into(),
                sample_rate: 8000,
                channels: 2,
                frames_per_chunk: 100,
                chunks_on_port: 20,
                epoch: 1,
            },
            recording: Recording {
                file: "x.wav".into(),
                first_frame: 151,
                frames: 400,
                seconds: 0.05,
                bytes: 3244,
                bits: 32,
                channels: vec![0, 1],
                gap_frames: 50 + 100,
                lost_frames: 100,
                end: "limit".into(),
                requested_first_frame: None,
                started_after_requested: 0,
                wav_format: None,
                in_progress: false,
            },
            losses: vec![Lost { first_frame: 301, frames: 100 }],
            chunks: vec![
                ChunkRow {
                    first_frame: 101,
                    frames: 100,
                    mono_ns: 1,
                    realtime_ns: 1,
                    flags: 1,
                    ..Default::default()
                },
                ChunkRow {
                    first_frame: 201,
                    frames: 100,
                    mono_ns: 2,
                    realtime_ns: 2,
                    bound_ns: Some(2000),
                    missing_channels: 0b10,
                    ..Default::default()
                },
                ChunkRow {
                    first_frame: 401,
                    frames: 100,
                    mono_ns: 4,
                    realtime_ns: 4,
                    flags: 1,
                    ..Default::default()
                },
                ChunkRow {
                    first_frame: 501,
                    frames: 100,
                    mono_ns: 5,
                    realtime_ns: 5,
                    bound_ns: Some(0),
                    unaligned_channels: 0b01,
                    ..Default::default()
                },
            ],
        }
    }

    #[test]
    fn a_consistent_sidecar_has_no_problems_and_answers_lookups() {
        let s = sample();
        assert_eq!(s.problems(), Vec::<String>::new());
        assert_eq!(s.last_frame(), 550);
        assert_eq!(s.row_of(150).map(|r| r.first_frame), Some(101));
        assert_eq!(s.row_of(350), None, "the lost chunk has no row");
        assert_eq!(s.row_of(600).map(|r| r.first_frame), Some(501));
        assert_eq!(s.row_of(601), None);
        assert!(s.is_lost(301) && s.is_lost(400) && !s.is_lost(300) && !s.is_lost(401));
    }

    /// A sidecar of `n` GAP chunks of 100 frames from frame 1, each losing frames 41..=50 of
    /// itself.
    fn gaps_with_losses(n: u64) -> Sidecar {
        let mut s = sample();
        s.chunks = (0..n)
            .map(|k| ChunkRow {
                first_frame: 1 + 100 * k,
                frames: 100,
                mono_ns: k,
                realtime_ns: k,
                flags: 1,
                ..Default::default()
            })
            .collect();
        s.losses = (0..n).map(|k| Lost { first_frame: 41 + 100 * k, frames: 10 }).collect();
        let r = &mut s.recording;
        (r.first_frame, r.frames, r.lost_frames, r.gap_frames) = (1, 100 * n, 10 * n, 90 * n);
        s
    }

    #[test]
    fn the_gap_frames_are_counted_in_one_walk_over_rows_and_losses() {
        for n in [10u64, 20_000] {
            let s = gaps_with_losses(n);
            assert_eq!(s.problems(), Vec::<String>::new(), "n = {n}");
            let (frames, steps) = s.gap_frames_walk();
            assert_eq!(frames, 90 * n);
            // One comparison per row and per loss (and one more per row that ends its scan);
            // a row × loss scan makes n² (4·10⁸ for 20 000 chunks).
            assert!(steps <= 3 * n + 1, "n = {n}: {steps} comparisons for {n} rows and {n} losses");
        }
        // A loss across many rows is counted in each of them, and only there.
        let mut s = gaps_with_losses(100);
        s.losses.truncate(50);
        s.losses.push(Lost { first_frame: 5001, frames: 5000 });
        let r = &mut s.recording;
        (r.lost_frames, r.gap_frames) = (50 * 10 + 5000, 50 * 90);
        assert_eq!(s.problems(), Vec::<String>::new());
        assert_eq!(s.gap_frames_walk().0, 50 * 90);
    }

    #[test]
    fn each_disagreement_is_named() {
        type Break = fn(&mut Sidecar);
        let cases: Vec<(Break, &str)> = vec![
            (|s| s.losses[0].frames = 300, "losses[0]: frames 301..=600 are not inside the file"),
            (|s| s.recording.lost_frames = 7, "lost_frames is 7; the losses sum to 100"),
            (|s| s.recording.gap_frames = 200, "gap_frames is 200; the GAP chunks hold 150"),
            (|s| s.chunks[1].first_frame = 202, "first_frame 202 does not start a chunk of 100"),
            (|s| s.chunks[2].flags = 0x40, "unknown flags 0x40"),
            (|s| s.chunks[3].first_frame = 601, "chunk 601 is outside the file"),
            (
                |s| s.recording.requested_first_frame = Some(1),
                "requested_first_frame 1 + started_after_requested 0",
            ),
            (|s| s.recording.channels = vec![2], "names channel 2; the port has 2"),
            (|s| s.chunks[1].missing_channels = 0b100, "(frame 201): missing_channels 0x4 names channel 2"),
            (
                |s| s.chunks[3].unaligned_channels = 1 << 63,
                "unaligned_channels 0x8000000000000000 names channel 63",
            ),
            (
                |s| s.chunks[0].bound_ns = Some(u64::MAX),
                "(frame 101): bound_ns 18446744073709551615 is the port's",
            ),
        ];
        for (break_it, want) in cases {
            let mut s = sample();
            break_it(&mut s);
            let p = s.problems();
            assert!(p.iter().any(|m| m.contains(want)), "{want:?} not in {p:?}");
        }
    }

    #[test]
    fn it_round_trips_through_json_and_accepts_older_sidecars() {
        let s = sample();
        let back: Sidecar = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
        assert_eq!(back, s);
        // A sidecar of an older recorder: no requested_first_frame, wav_format or in_progress.
        let old = r#"{"acquisition":{"device":"d","format":"S32_LE","sample_rate":8000,"channels":1,
            "frames_per_chunk":10,"chunks_on_port":4,"epoch":1},"recording":{"file":"a.wav",
            "first_frame":1,"frames":10,"seconds":0.00125,"bytes":84,"bits":32,"channels":[0],
            "gap_frames":0,"lost_frames":0,"end":"limit"},"losses":[],"chunks":[]}"#;
        let s: Sidecar = serde_json::from_str(old).unwrap();
        assert_eq!(s.problems(), Vec::<String>::new());
        // A row of a recorder before port format 2.4: no bound, no masks.
        let row: ChunkRow =
            serde_json::from_str(r#"{"first_frame":1,"frames":10,"mono_ns":5,"realtime_ns":6,"flags":4}"#)
                .unwrap();
        assert_eq!((row.bound_ns, row.missing_channels, row.unaligned_channels), (None, 0, 0));
        assert_eq!(row.bound_or_unknown(), BOUND_UNKNOWN);
    }

    #[test]
    fn a_row_writes_its_bound_and_masks_only_when_known_or_set() {
        let s = sample();
        let json: Vec<String> = s.chunks.iter().map(|r| serde_json::to_string(r).unwrap()).collect();
        assert!(!json[0].contains("bound_ns") && !json[0].contains("channels"), "{}", json[0]);
        assert!(json[1].ends_with(r#""flags":0,"bound_ns":2000,"missing_channels":2}"#), "{}", json[1]);
        assert!(json[3].ends_with(r#""bound_ns":0,"unaligned_channels":1}"#), "{}", json[3]);
    }
}
