//! Replay of a recording as a capture device, paced in real time, one chunk at a time. The
//! recording is a WAV file with its sidecar, or an MCAP recording of `bass record --format mcap`
//! (a `.mcap` file or its bag directory, read by [`super::mcap_file`] into the same frames and
//! sidecar), the replay the same for both:
//!
//! - `sim:file:PATH.wav` — with the sidecar `PATH.wav.json` that `bass record` writes, the
//!   recording comes back as the live port had it: **at its recorded frame indices** (the port
//!   starts at the recording's first frame; the frames before it are lost for readers, never
//!   zeros), **every chunk with its recorded flags** (GAP, DISCONTINUITY, TIME_ESTIMATED, LATE;
//!   GAP chunks at the start, at the end, everywhere) and CLOCK_REALTIME timestamp
//!   (CLOCK_MONOTONIC ones keep their recorded spacing, moved by one constant onto this boot's
//!   clock), and **the recorder's losses as losses**: the port skips ahead over them
//!   (`Writer::skip_to`), so a reader keeping up gets the same `loss` at the same frame as the
//!   recorder did (a reader further behind also loses what was still before it, as when a
//!   live port overtakes it). That needs the recording's chunk size; another is refused.
//!   A loss of any length is passed over **in one step**: the chunk after it follows the chunk
//!   before it one chunk period later (the replay does not wait out the time of the loss, so a
//!   loss of hours neither stalls the port nor keeps the replay waiting); the CLOCK_MONOTONIC
//!   stamps keep the recorded spacing, so after a loss they are ahead of the replay's clock by
//!   the time it did not wait. A loss that runs to the recording's end moves the port on over
//!   it one chunk period after the last chunk, then the replay ends. A recording whose frames
//!   (lost or not) pass frame [`MAX_REPLAY_FRAME`] is refused.
//!   Without a sidecar: WAV frame 0 becomes frame 1, flags 0, the replay's own timestamps.
//! - `sim:file-renumber:PATH.wav` — the same, but WAV frame 0 becomes frame 1 (the recorded
//!   flags and times are kept where the chunk grids agree; elsewhere GAP frames still replay as
//!   GAP, DISCONTINUITY marks a chunk holding some, and timestamps are the replay's).
//! - `sim:file-loop:PATH.wav` — renumbered, and starts again at its end; GAP runs are kept,
//!   losses replay as the zeros the file holds.
//!
//! A recording that ends inside a chunk is completed with zero frames (the end-of-recording
//! message says how many). Samples are left-justified to S32 (a 32-bit recording replays bit
//! for bit; a 16- or 24-bit one as its value shifted left; float as value × 2³¹, clipped).
//! The rate and channel count of the Acquire must be the file's: anything else is refused.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use bassport::format::{chunk_flags, error_code};
use bassport::sys::{monotonic_ns, realtime_ns};
use bassport::ChunkMeta;

use super::mcap_file::{self, McapFrames};
use super::regular;
use super::{sleep_until, ReadEvent, StopSignal};
use basskit::sidecar::Sidecar;

const NS_PER_MS: u64 = 1_000_000;
/// Longest sleep of one read: a longer wait returns `Pending` in between.
const PENDING_SLICE_NS: u64 = 100 * NS_PER_MS;
/// Largest frame index a replay accepts, lost frames included: 2^53, the last integer a double
/// holds exactly (Matlab, Python floats), 5.9 thousand years of frames at 48 kHz. A recording
/// past it is a forged one.
pub const MAX_REPLAY_FRAME: u64 = 1 << 53;

/// How a file is replayed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// `sim:file:` — at the recorded frame indices when a sidecar says them.
    Recorded,
    /// `sim:file-renumber:` — from frame 1.
    Renumber,
    /// `sim:file-loop:` — from frame 1, again and again.
    Loop,
}

impl Mode {
    /// The device-name prefix after `sim:`.
    pub fn prefix(self) -> &'static str {
        match self {
            Mode::Recorded => "file:",
            Mode::Renumber => "file-renumber:",
            Mode::Loop => "file-loop:",
        }
    }
}

/// What a port frame of the replay holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// Before the recording's first frame or after its last: no frame of the file.
    Outside,
    /// A frame the recorder lost.
    Lost,
    /// A frame of a GAP chunk.
    Gap,
    /// A frame of audio.
    Data,
}

/// What the replay gave back so far (for the end-of-recording message).
#[derive(Default, Debug)]
struct Replayed {
    /// Frames of the file published.
    frames: u64,
    /// Of them, in GAP chunks.
    gap: u64,
    /// Frames the recorder lost, replayed as lost.
    lost: u64,
    /// Zero frames completing the last chunk.
    padded: u64,
    /// First and last port frame of the file published.
    first: Option<u64>,
    last: u64,
}

/// Where the frames of a recording come from.
enum Frames {
    /// A WAV file: its samples, left-justified to S32.
    Wav { reader: hound::WavReader<BufReader<File>>, spec: hound::WavSpec, pos: u64 },
    /// An MCAP recording's audio messages (S32 as captured).
    Mcap(Box<McapFrames>),
}

/// A recording replayed as a device.
pub struct FileDevice {
    path: PathBuf,
    frames: Frames,
    mode: Mode,
    sidecar: Option<Sidecar>,
    rate: u64,
    channels: usize,
    nfpc: u64,
    /// Frames of the file replayed.
    total: u64,
    /// Port frame of WAV frame 0.
    base: u64,
    /// Recorded frame of WAV frame 0 (`base` without a sidecar).
    rec_first: u64,
    /// The port's chunks are the recording's: each chunk's row gives its flags and times.
    exact: bool,
    /// First port frame of the next chunk.
    next: u64,
    /// First port frame of the first chunk (the pacing origin).
    origin: u64,
    start_ns: u64,
    /// Recorded CLOCK_MONOTONIC + this = the replay's, set by the first chunk with a row.
    mono_offset: Option<i128>,
    done: Replayed,
    /// The chunk prepared while waiting for its time.
    ready: Option<(u64, u64, Counts)>,
    /// Frames of the recorded losses passed over in one step: the pacing leaves out their time.
    skipped: u64,
    /// CLOCK_MONOTONIC at which the last chunk was due.
    last_due: u64,
}

/// Opens `path` for an Acquire at `rate` Hz with `channels` channels and `nfpc` frames per chunk.
pub fn open(path: &Path, mode: Mode, rate: u32, channels: u32, nfpc: u32) -> Result<FileDevice, String> {
    if mcap_file::is_mcap(path) {
        return open_mcap(path, mode, rate, channels, nfpc);
    }
    let name = format!("sim:{}{}", mode.prefix(), path.display());
    let reader = hound::WavReader::new(BufReader::new(regular::open(path, "WAV")?))
        .map_err(|e| format!("sim:file:{}: cannot read the WAV file: {e}", path.display()))?;
    let spec = reader.spec();
    check_shape(&name, spec.sample_rate, spec.channels, rate, channels)?;
    let float_ok = spec.sample_format == hound::SampleFormat::Float && spec.bits_per_sample == 32;
    if spec.sample_format == hound::SampleFormat::Int && !(8..=32).contains(&spec.bits_per_sample)
        || !float_ok && spec.sample_format == hound::SampleFormat::Float
    {
        return Err(format!(
            "{name}: {}-bit {:?} samples are not supported",
            spec.bits_per_sample, spec.sample_format
        ));
    }
    let mut total = u64::from(reader.duration());
    if total == 0 {
        return Err(format!("{name} holds no frames"));
    }
    let sidecar = Sidecar::load_for(path)
        .map_err(|e| format!("{name}: {e}; fix it or move it away to replay the WAV alone"))?;
    if let Some(sc) = &sidecar {
        let (a, r) = (&sc.acquisition, &sc.recording);
        if a.sample_rate != spec.sample_rate || r.channels.len() != usize::from(spec.channels) {
            return Err(format!(
                "{name}: the sidecar says {} Hz, {} channel(s); the WAV holds {} Hz, {} channel(s)",
                a.sample_rate,
                r.channels.len(),
                spec.sample_rate,
                spec.channels
            ));
        }
        if r.frames > total || r.frames < total && !r.in_progress {
            return Err(format!(
                "{name}: the sidecar says {} frames; the WAV holds {total} (check the pair with bass record --check)",
                r.frames
            ));
        }
        // A checkpoint of a recorder that was killed: the frames it vouches for.
        total = r.frames;
    }
    let frames = Frames::Wav { reader, spec, pos: 0 };
    device(path, &name, frames, sidecar, total, mode, rate, channels, nfpc)
}

/// Refuses an Acquire whose rate or channel count is not the recording's.
fn check_shape(
    name: &str,
    file_rate: u32,
    file_channels: u16,
    rate: u32,
    channels: u32,
) -> Result<(), String> {
    if file_rate != rate || u32::from(file_channels) != channels {
        return Err(format!(
            "{name} holds {file_rate} Hz, {file_channels} channel(s); the Acquire asks for {rate} Hz, {channels} channel(s): use --rate {file_rate} --channels {file_channels}"
        ));
    }
    Ok(())
}

/// `open` for an MCAP recording (a `.mcap` file or a bag directory holding one).
fn open_mcap(path: &Path, mode: Mode, rate: u32, channels: u32, nfpc: u32) -> Result<FileDevice, String> {
    let name = format!("sim:{}{}", mode.prefix(), path.display());
    let file = mcap_file::resolve(path).map_err(|e| format!("{name}: {e}"))?;
    let (frames, side) =
        mcap_file::open(&file, regular::open(&file, "MCAP")?).map_err(|e| format!("{name}: {e}"))?;
    let file_channels = u16::try_from(side.recording.channels.len()).unwrap_or(u16::MAX);
    check_shape(&name, side.acquisition.sample_rate, file_channels, rate, channels)?;
    let total = side.recording.frames;
    device(path, &name, Frames::Mcap(Box::new(frames)), Some(side), total, mode, rate, channels, nfpc)
}

/// The replay of `total` frames from `frames`, described by `sidecar` if there is one.
#[allow(clippy::too_many_arguments)]
fn device(
    path: &Path,
    name: &str,
    frames: Frames,
    sidecar: Option<Sidecar>,
    total: u64,
    mode: Mode,
    rate: u32,
    channels: u32,
    nfpc: u32,
) -> Result<FileDevice, String> {
    let nfpc = u64::from(nfpc.max(1));
    let (mut base, mut rec_first, mut exact) = (1, 1, false);
    if total == 0 {
        return Err(format!("{name} holds no frames"));
    }
    if let Some(sc) = &sidecar {
        let a = &sc.acquisition;
        rec_first = sc.recording.first_frame;
        let same_chunks = u64::from(a.frames_per_chunk) == nfpc;
        match mode {
            Mode::Recorded if !same_chunks => {
                return Err(format!(
                    "{name} was recorded with {} frames per chunk; replaying it at its frame indices needs \
                     the same chunks: use --frames {} (or sim:file-renumber:{} to replay it from frame 1)",
                    a.frames_per_chunk,
                    a.frames_per_chunk,
                    path.display()
                ))
            }
            Mode::Recorded => (base, exact) = (rec_first, true),
            Mode::Renumber => exact = same_chunks && (rec_first - 1) % nfpc == 0,
            Mode::Loop => {}
        }
    }
    check_bound(name, sidecar.as_ref(), rec_first, total)?;
    let origin = (base - 1) / nfpc * nfpc + 1;
    Ok(FileDevice {
        path: path.to_owned(),
        frames,
        mode,
        sidecar,
        rate: u64::from(rate),
        channels: channels as usize,
        nfpc,
        total,
        base,
        rec_first,
        exact,
        next: origin,
        origin,
        start_ns: 0,
        mono_offset: None,
        done: Replayed::default(),
        ready: None,
        skipped: 0,
        last_due: 0,
    })
}

/// Refuses a recording whose frames `rec_first ..` (`total` of them, lost ones included) pass
/// [`MAX_REPLAY_FRAME`], naming the loss that does if one does.
fn check_bound(name: &str, sidecar: Option<&Sidecar>, rec_first: u64, total: u64) -> Result<(), String> {
    let last = rec_first.saturating_add(total - 1);
    if last <= MAX_REPLAY_FRAME {
        return Ok(());
    }
    let loss = sidecar.and_then(|sc| {
        sc.losses.iter().find(|l| l.first_frame.saturating_add(l.frames - 1) > MAX_REPLAY_FRAME)
    });
    Err(match loss {
        Some(l) => format!(
            "{name}: its loss of {} frames from frame {} runs past frame {MAX_REPLAY_FRAME} (2^53), the largest frame index a replay accepts",
            l.frames, l.first_frame
        ),
        None => format!(
            "{name}: its frames {rec_first}..={last} run past frame {MAX_REPLAY_FRAME} (2^53), the largest frame index a replay accepts"
        ),
    })
}

/// The GAP flag of a sidecar row.
fn is_gap(flags: u32) -> bool {
    flags & chunk_flags::GAP != 0
}

impl FileDevice {
    /// CLOCK_MONOTONIC at which port frame `p` is due (the replay's clock, which leaves out
    /// the time of the losses passed over).
    fn due_ns(&self, p: u64) -> u64 {
        let k = p.saturating_sub(self.origin).saturating_sub(self.skipped);
        self.start_ns + (u128::from(k) * 1_000_000_000 / u128::from(self.rate)) as u64
    }

    /// The CLOCK_MONOTONIC stamp of port frame `p`: its place in the recording's time, where
    /// every frame takes 1/rate, lost or not (ahead of the replay's clock by the losses
    /// passed over).
    fn stamp_ns(&self, p: u64) -> u64 {
        let k = p.saturating_sub(self.origin);
        self.start_ns.saturating_add(
            (u128::from(k) * 1_000_000_000 / u128::from(self.rate)).min(u128::from(u64::MAX)) as u64,
        )
    }

    /// Last port frame of the file (none for a loop).
    fn last(&self) -> Option<u64> {
        (self.mode != Mode::Loop).then(|| self.base + self.total - 1)
    }

    /// WAV frame of port frame `p`, if the file has one.
    fn wav_frame(&self, p: u64) -> Option<u64> {
        let i = p.checked_sub(self.base)?;
        match self.mode {
            Mode::Loop => Some(i % self.total),
            _ => (i < self.total).then_some(i),
        }
    }

    fn kind(&self, p: u64) -> Kind {
        let Some(i) = self.wav_frame(p) else { return Kind::Outside };
        let Some(sc) = &self.sidecar else { return Kind::Data };
        let r = self.rec_first + i;
        if self.mode != Mode::Loop && sc.is_lost(r) {
            Kind::Lost
        } else if sc.row_of(r).is_some_and(|row| is_gap(row.flags)) {
            Kind::Gap
        } else {
            Kind::Data
        }
    }

    /// Reads `n` frames from file frame `i` into `out` (interleaved, left-justified S32).
    fn fill(&mut self, i: u64, out: &mut [i32], n: usize) -> Result<(), String> {
        let want = n * self.channels;
        let (reader, spec, pos) = match &mut self.frames {
            Frames::Mcap(m) => return m.fill(i, &mut out[..want], n),
            Frames::Wav { reader, spec, pos } => (reader, spec, pos),
        };
        if *pos != i {
            let to = u32::try_from(i).map_err(|_| format!("frame {i} is past a WAV file's reach"))?;
            reader.seek(to).map_err(|e| e.to_string())?;
            *pos = i;
        }
        let shift = 32 - u32::from(spec.bits_per_sample);
        let mut got = 0;
        if spec.sample_format == hound::SampleFormat::Float {
            for (o, s) in out[..want].iter_mut().zip(reader.samples::<f32>()) {
                let x = s.map_err(|e| e.to_string())?;
                *o = (f64::from(x) * 2_147_483_648.0).round().clamp(f64::from(i32::MIN), f64::from(i32::MAX))
                    as i32;
                got += 1;
            }
        } else {
            for (o, s) in out[..want].iter_mut().zip(reader.samples::<i32>()) {
                *o = s.map_err(|e| e.to_string())?.wrapping_shl(shift);
                got += 1;
            }
        }
        if got < want {
            return Err(format!("the file ended early ({got} of {want} samples)"));
        }
        *pos += n as u64;
        Ok(())
    }

    /// Fills `out` with port frames `p0 .. p0 + n` (zeros where the file has none).
    fn fill_chunk(&mut self, p0: u64, out: &mut [i32]) -> Result<(), String> {
        let n = self.nfpc as usize;
        out[..n * self.channels].fill(0);
        let mut k = 0usize;
        while k < n {
            let Some(i) = self.wav_frame(p0 + k as u64) else {
                k += 1;
                continue;
            };
            let run = (n - k).min((self.total - i) as usize);
            let ch = self.channels;
            self.fill(i, &mut out[k * ch..(k + run) * ch], run)?;
            k += run;
        }
        Ok(())
    }

    /// The first port frame after the recorded loss that holds port frame `p`, if one does
    /// (a binary search of the losses; none in a loop, which replays them as zeros).
    fn loss_end(&self, p: u64) -> Option<u64> {
        let sc = self.sidecar.as_ref().filter(|_| self.mode != Mode::Loop)?;
        let r = self.rec_first + self.wav_frame(p)?;
        let k = sc.losses.partition_point(|l| l.first_frame <= r);
        let l = sc.losses.get(k.checked_sub(1)?)?;
        let end = l.first_frame + l.frames;
        (r < end).then(|| p + (end - r))
    }

    /// The next chunk holding a frame of the file, as (first frame, first readable frame,
    /// frames by kind); chunks lost whole are passed over in one step (the port skips them
    /// with it), so the work is the same for a loss of a chunk or of 2^53 frames. `None` at
    /// the end of the file.
    fn prepare(&mut self) -> Option<(u64, u64, Counts)> {
        loop {
            let p0 = self.next;
            if self.last().is_some_and(|l| p0 > l) {
                return None;
            }
            let whole = self.loss_end(p0).map_or(0, |end| (end - p0) / self.nfpc * self.nfpc);
            if whole > 0 {
                self.next = p0 + whole;
                self.done.lost += whole;
                self.skipped += whole;
                continue;
            }
            let mut c = Counts::default();
            let mut readable_from = None;
            for p in p0..p0 + self.nfpc {
                match self.kind(p) {
                    Kind::Outside if p >= self.base => c.after += 1,
                    Kind::Outside => {}
                    Kind::Lost if readable_from.is_none() => c.lost += 1,
                    Kind::Lost => c.late_lost += 1,
                    k => {
                        readable_from.get_or_insert(p);
                        if k == Kind::Gap {
                            c.gap += 1;
                        } else {
                            c.data += 1;
                        }
                    }
                }
            }
            self.next = p0 + self.nfpc;
            self.done.lost += c.lost;
            if let Some(r) = readable_from {
                return Some((p0, r, c));
            }
        }
    }

    fn failed(&self, what: &str) -> ReadEvent {
        ReadEvent::Failed {
            code: error_code::DEVICE_LOST,
            message: format!("sim:{}{}: {what}", self.mode.prefix(), self.path.display()),
        }
    }

    /// The end of the recording: at once, or — a recorded loss running to the end — one chunk
    /// period after the last chunk, when the next one would have come, so that readers have
    /// the time to read the last chunk before the port moves on over the loss.
    fn end(&mut self, stop: &StopSignal) -> ReadEvent {
        let ev = self.ended();
        if matches!(ev, ReadEvent::Ended { lost_to: Some(_), .. }) {
            let chunk_ns = (u128::from(self.nfpc) * 1_000_000_000 / u128::from(self.rate)) as u64;
            let due = self.last_due.max(self.start_ns) + chunk_ns;
            let slice_end = monotonic_ns() + PENDING_SLICE_NS;
            if due > slice_end {
                return if sleep_until(slice_end, stop) { ReadEvent::Pending } else { ReadEvent::Stopped };
            }
            if !sleep_until(due, stop) {
                return ReadEvent::Stopped;
            }
        }
        ev
    }

    fn ended(&self) -> ReadEvent {
        let d = &self.done;
        let (first, last) = (d.first.unwrap_or(self.base), d.last);
        let at = if self.mode == Mode::Recorded && self.sidecar.is_some() {
            "at the recorded indices"
        } else {
            "renumbered from frame 1"
        };
        let pad = if d.padded > 0 {
            format!(
                "; the last chunk is completed with {} zero frames (to frame {})",
                d.padded,
                last + d.padded
            )
        } else {
            String::new()
        };
        // A loss running to the end: the port moves on over it before the replay ends.
        let lost_to = self.last().filter(|&l| l > d.last && self.loss_end(l).is_some()).map(|l| l + 1);
        ReadEvent::Ended {
            lost_to,
            message: format!(
                "sim:{}{}: end of the recording after {} frames (frames {first}..={last} {at}, {} of them GAP, \
                 {} lost as in the recording{pad}) (replay ended)",
                self.mode.prefix(),
                self.path.display(),
                d.frames,
                d.gap,
                d.lost
            ),
        }
    }

    /// The flags and timestamps of the chunk at port frame `p0`, and whether it is GAP.
    fn meta(&mut self, p0: u64, counts: &Counts, late: bool) -> (ChunkMeta, bool) {
        let row = if self.exact {
            let r0 = p0 + self.rec_first - self.base;
            self.sidecar.as_ref().and_then(|sc| sc.row_of(r0).filter(|row| row.first_frame == r0).copied())
        } else {
            None
        };
        if let Some(row) = row {
            let at = i128::from(self.stamp_ns(p0));
            let off = *self.mono_offset.get_or_insert(at - i128::from(row.mono_ns));
            let mono = (i128::from(row.mono_ns) + off).clamp(1, i128::from(u64::MAX)) as u64;
            // The recorded bound holds around the shifted stamp too (the shift is exact).
            let meta = ChunkMeta {
                mono_ns: mono,
                realtime_ns: row.realtime_ns.max(1),
                flags: row.flags,
                bound_ns: row.bound_ns,
                missing_channels: row.missing_channels,
                unaligned_channels: row.unaligned_channels,
            };
            return (meta, is_gap(row.flags));
        }
        let zeros = counts.gap > 0 && counts.data == 0;
        let mut flags = if zeros {
            chunk_flags::GAP
        } else if counts.gap > 0 {
            chunk_flags::DISCONTINUITY
        } else {
            0
        };
        if self.exact {
            // The recorder never saw this chunk's row: its times are the replay's own.
            flags |= chunk_flags::TIME_ESTIMATED;
        } else if late {
            flags |= chunk_flags::LATE;
        }
        let mono = self.stamp_ns(p0);
        let realtime = realtime_ns().wrapping_add(mono).wrapping_sub(monotonic_ns());
        (
            ChunkMeta { mono_ns: mono.max(1), realtime_ns: realtime.max(1), flags, ..ChunkMeta::default() },
            zeros,
        )
    }
}

/// The frames of one port chunk by kind.
#[derive(Default)]
struct Counts {
    /// Lost frames before the first readable one (replayed as lost).
    lost: u64,
    gap: u64,
    data: u64,
    /// Frames after the file's end.
    after: u64,
    /// Lost frames after the first readable one (replayed as the file's zeros).
    late_lost: u64,
}

mod capture;
#[cfg(test)]
mod tests;
