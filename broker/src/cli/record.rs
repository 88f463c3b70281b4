//! `bass record FILE.wav`: reads the port losslessly (futex waits; a reader that keeps up
//! never loses frames) and writes a WAV file ([`super::wav`]) plus a sidecar `FILE.wav.json`
//! ([`crate::sidecar`]: the acquisition and one row per chunk — first frame,
//! CLOCK_MONOTONIC / CLOCK_REALTIME ns, flags), so the recording can be aligned with the
//! robot's other sensors; and `bass record --check FILE.wav`, which verifies such a pair.
//!
//! WAV frame `i` is frame `first_frame + i` of the acquisition: frames the recorder lost
//! inside the file (the port overtook it) are written as zeros and listed in the sidecar, so
//! the recording is never silently shortened. Reads end on chunk boundaries, so such a loss
//! starts on a chunk. A start the port no longer had is not a loss: the file starts at the
//! first frame the port still had. The header and the sidecar are checkpointed together while
//! recording, and made to agree with what reached the disk when a write fails.
//! See docs/broker.md for the options, the rounding and what a kill loses.

use std::fs::{File, OpenOptions};
use std::io::{self, IsTerminal, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use bassclient::format::chunk_flags;
use bassclient::{Error, Port};

use super::blocks::{dbfs, levels};
use super::exit::{self, Exit};
use super::follow::{after_stop, open_port, AfterStop};
use super::wav;
use crate::cli::parse_seconds;
use crate::sidecar::{self, ChunkRow, Lost, Sidecar};

/// Largest data chunk a RIFF/WAV file can describe (its sizes are 32-bit).
const WAV_LIMIT: u64 = u32::MAX as u64 - 64;

/// Where the recording starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum From {
    /// The oldest frame still on the port (the seconds that just happened).
    Oldest,
    /// The next frame published.
    Now,
    /// An absolute frame index (>= 1).
    Frame(u64),
}

fn parse_from(s: &str) -> Result<From, String> {
    match s {
        "oldest" => Ok(From::Oldest),
        "now" => Ok(From::Now),
        _ => match s.parse::<u64>() {
            Ok(f) if f >= 1 => Ok(From::Frame(f)),
            _ => Err(format!("{s:?}: use oldest, now or a frame index >= 1")),
        },
    }
}

fn parse_bits(s: &str) -> Result<u16, String> {
    match s {
        "16" => Ok(16),
        "24" => Ok(24),
        "32" => Ok(32),
        _ => Err(format!("{s:?}: use 16, 24 or 32")),
    }
}

/// Options of `bass record`.
#[derive(clap::Args, Debug, Clone)]
pub struct RecordArgs {
    /// Output WAV file (the sidecar is FILE.json next to it, e.g. rec.wav.json)
    pub file: PathBuf,
    /// Verify FILE and its sidecar instead of recording (exit 0 and one "ok" line, else 1)
    #[arg(long)]
    pub check: bool,
    /// WAV header: auto (EXTENSIBLE above 16 bits or 2 channels), pcm (plain, for any
    /// reader) or extensible
    #[arg(long, value_name = "KIND", default_value = "auto")]
    pub wav_format: WavFormat,
    /// Bits per sample: 32 (as captured), 24 or 16 (rounded half up, saturating)
    #[arg(short = 'b', long, default_value_t = 32, value_parser = parse_bits)]
    pub bits: u16,
    /// Channels to record, e.g. 0,1 [default: all]
    #[arg(long, value_name = "LIST", value_delimiter = ',',
          value_parser = clap::value_parser!(u32).range(0..64))]
    pub channels: Option<Vec<u32>>,
    /// Stop after S seconds of audio (converted to frames at the port's rate)
    #[arg(short = 'd', long, value_name = "S", value_parser = parse_seconds, conflicts_with = "frames")]
    pub duration: Option<f64>,
    /// Stop after N frames
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub frames: Option<u64>,
    /// First frame: oldest (still on the port), now (the next one published) or an index
    #[arg(long, value_name = "WHERE", default_value = "now", value_parser = parse_from)]
    pub from: From,
    /// Overwrite FILE and its sidecar if they exist (never through a symbolic link)
    #[arg(long)]
    pub force: bool,
    /// No progress output
    #[arg(short = 'q', long)]
    pub quiet: bool,
    /// Print the summary as one JSON object
    #[arg(long)]
    pub json: bool,
}

/// Converts a captured (left-justified S32) sample to `bits`, rounding half up and saturating.
pub fn convert(s: i32, bits: u16) -> i32 {
    let shift = 32 - u32::from(bits);
    if shift == 0 {
        return s;
    }
    let max = (1i64 << (bits - 1)) - 1;
    ((i64::from(s) + (1i64 << (shift - 1))) >> shift).min(max) as i32
}

/// How often the header and the sidecar are brought up to date at least (see [`Checkpoints`]).
const CHECKPOINT_EVERY: Duration = Duration::from_secs(1);
/// A checkpoint may take at most this share of the time between two (1 %).
const CHECKPOINT_SHARE: u32 = 100;
/// `recording.end` of a checkpoint.
const IN_PROGRESS: &str = "in progress (a checkpoint; the recorder had not ended)";

/// Runs `bass record` on broker `name` (or `bass record --check`).
pub fn run(name: &str, a: &RecordArgs, timeout: Duration) -> Result<()> {
    if a.check {
        return match check(&a.file) {
            Ok(line) => {
                println!("{line}");
                Ok(())
            }
            Err(problems) => Err(Exit::new(
                exit::FAILURE,
                format!(
                    "{} and its sidecar disagree ({} problems):\n  {}",
                    a.file.display(),
                    problems.len(),
                    problems.join("\n  ")
                ),
            )
            .into()),
        };
    }
    let side_path = sidecar::path_of(&a.file);
    for p in [&a.file, &side_path] {
        refuse_path(p, a.force)?;
    }
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&stop)).context("install the signal handlers")?;
    }
    let port = open_port(name, timeout, None)?;
    let g = port.geometry().clone();
    let channels: Vec<u32> = a.channels.clone().unwrap_or_else(|| (0..g.channels).collect());
    if let Some(c) = channels.iter().find(|&&c| c >= g.channels) {
        return Err(Exit::new(
            exit::USAGE,
            format!("--channels: the port has {} channels (0..={}), not {c}", g.channels, g.channels - 1),
        )
        .into());
    }
    let format = match a.wav_format {
        WavFormat::Auto => wav::Format::required(a.bits, channels.len() as u16),
        WavFormat::Pcm => wav::Format::Pcm,
        WavFormat::Extensible => wav::Format::Extensible,
    };
    let spec =
        wav::Spec { channels: channels.len() as u16, sample_rate: g.sample_rate, bits: a.bits, format };
    let frame_bytes = spec.frame_bytes();
    let max_frames = (WAV_LIMIT - format.header_len()) / frame_bytes;
    let limit = match (a.frames, a.duration) {
        (Some(n), _) => Some(n),
        (None, Some(s)) => Some(((s * f64::from(g.sample_rate)).round() as u64).max(1)),
        (None, None) => None,
    };
    if let Some(n) = limit {
        if n > max_frames {
            return Err(Exit::new(exit::USAGE, format!(
                "{n} frames of {frame_bytes} bytes exceed the 4 GiB limit of a WAV file; record in several files (at most {max_frames} frames each)")).into());
        }
    }
    let info = port.info()?;
    let device_format = bassclient::control::Client::connect(name)
        .and_then(|mut c| {
            c.set_timeout(timeout)?;
            c.status()
        })
        .map(|s| s.format)
        .unwrap_or_default();
    let acquisition = sidecar::Acquisition {
        device: info.device.clone(),
        format: device_format,
        sample_rate: g.sample_rate,
        channels: g.channels,
        frames_per_chunk: g.frames_per_chunk,
        chunks_on_port: g.chunks_on_port,
        epoch: port.epoch(),
    };
    let lfi = info.last_frame_index;
    let requested = match a.from {
        From::Now => lfi + 1,
        From::Oldest => (lfi + 1).saturating_sub(port.frames_on_port()).max(1),
        From::Frame(f) => f,
    };
    if requested > lfi + 1 && !a.quiet {
        eprintln!(
            "bass record: waiting for frame {requested}; the port is at frame {lfi} ({:.1} s away at {} Hz)",
            (requested - lfi) as f64 / f64::from(g.sample_rate),
            g.sample_rate
        );
    }
    let wav_file = create(&a.file, a.force)?;
    let side_file = match create(&side_path, a.force) {
        Ok(f) => f,
        Err(e) => {
            let _ = std::fs::remove_file(&a.file);
            return Err(e);
        }
    };
    let mut rec = Recording {
        file: a.file.clone(),
        side_path,
        acquisition,
        channels: channels.clone(),
        requested,
        first: None,
        next: requested,
        rows: Vec::new(),
        gap_count: 0,
        losses: Vec::new(),
        wav: wav::Writer::new(wav_file, spec).with_context(|| format!("write {}", a.file.display()))?,
    };
    rec.write_first_checkpoint(side_file).with_context(|| format!("write {}", rec.side_path.display()))?;
    let mut checkpoints = Checkpoints::new();
    let progress = Progress::new(a.quiet, limit, g.sample_rate);
    let mut peaks = vec![0f64; channels.len()];
    let mut last_progress = Instant::now();
    let end: Result<String, Ended> = loop {
        if stop.load(Ordering::Relaxed) {
            break Ok("signal".into());
        }
        let written = rec.wav.frames();
        if limit.is_some_and(|l| written >= l) {
            break Ok("limit".into());
        }
        if written >= max_frames {
            break Ok(format!("4 GiB WAV limit reached at frame {}", rec.next - 1));
        }
        let started = rec.first.is_some();
        let step = rec.step(&port, Some(limit.unwrap_or(max_frames)), &mut peaks);
        match (started, rec.first) {
            (false, Some(f)) if f > requested && !a.quiet => eprintln!(
                "bass record: started {} frames after the requested frame {requested}, at frame {f} (the port no longer had the frames before it)",
                f - requested
            ),
            _ => {}
        }
        match step {
            Ok(()) => {}
            Err(Step::Idle) => {}
            Err(Step::Wait(e)) => match e {
                Error::Restarted => break Ok("a new acquisition started; the recording ends here".into()),
                Error::Stopped { .. } => match after_stop(name, &port, timeout) {
                    Ok(AfterStop::Restarted) => {
                        break Ok("a new acquisition started; the recording ends here".into())
                    }
                    Ok(AfterStop::Stopped) => {
                        break Ok(format!("acquisition stopped at frame {}", rec.next - 1))
                    }
                    Err(e) => break Err(Ended::Other(e)),
                },
                Error::Device { code, message } => {
                    break Err(Ended::Other(
                        Exit::new(
                            exit::DEVICE_ENDED,
                            format!("the acquisition ended on a device error (code {code}): {message}"),
                        )
                        .into(),
                    ))
                }
                e @ Error::WriterGone { .. } => {
                    break Err(Ended::Other(Exit::new(exit::NO_BROKER, e.to_string()).into()))
                }
                e => break Err(Ended::Other(e.into())),
            },
            Err(Step::Disk(e)) => break Err(Ended::Disk(e)),
        }
        if let Err(e) = checkpoints.poll(&mut rec) {
            break Err(Ended::Disk(e));
        }
        if last_progress.elapsed() >= Duration::from_secs(1) {
            last_progress = Instant::now();
            let lost = rec.losses.iter().map(|l| l.frames).sum();
            progress.update(rec.wav.frames(), rec.wav.frames() * frame_bytes, rec.gap_count, lost, &peaks);
            peaks.iter_mut().for_each(|p| *p = 0.0);
        }
    };
    progress.finish();
    // A checkpoint still being written: wait for it (it must not patch the final header);
    // its failure (a full disk) is handled by `finish` like any other.
    let _ = checkpoints.wait();
    let (reason, failure) = match end {
        Ok(r) => (r, None),
        Err(Ended::Disk(e)) => (format!("{e}"), Some(Ended::Disk(e))),
        Err(Ended::Other(e)) => (format!("{e:#}"), Some(Ended::Other(e))),
    };
    let side = match (rec.finish(&reason), failure.as_ref()) {
        (Err(e), _) => {
            return Err(Exit::new(
                exit::FAILURE,
                format!(
                    "{}: the recording ended ({reason}), but its sidecar {} could not be written: {e}",
                    a.file.display(),
                    rec.side_path.display()
                ),
            )
            .into())
        }
        (Ok((side, cut)), f) if cut > 0 || matches!(f, Some(Ended::Disk(_))) => {
            let e = match f {
                Some(Ended::Disk(e)) => e.to_string(),
                _ => "no space left for the sidecar".into(),
            };
            let room = if cut > 0 {
                format!(" ({cut} frames cut to make room for the sidecar)")
            } else {
                String::new()
            };
            return Err(Exit::new(
                exit::FAILURE,
                format!(
                    "{}: {e}: the recording ends with {} frames written{room}; the header and the sidecar {} describe them",
                    a.file.display(),
                    side.recording.frames,
                    rec.side_path.display()
                ),
            )
            .into());
        }
        (Ok((side, _)), _) => side,
    };
    let r = &side.recording;
    if a.json {
        println!("{}", serde_json::to_string(r)?);
    } else if !a.quiet {
        println!(
            "recorded {} frames ({:.3} s) from frame {} to {}: {} bytes, {} gap frames, {} frames lost by the recorder; {}; sidecar {}",
            r.frames,
            r.seconds,
            r.first_frame,
            a.file.display(),
            r.bytes,
            r.gap_frames,
            r.lost_frames,
            r.end,
            rec.side_path.display()
        );
    }
    match failure {
        Some(Ended::Other(e)) => Err(e),
        _ => Ok(()),
    }
}

/// `--wav-format`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum WavFormat {
    /// WAVE_FORMAT_EXTENSIBLE where the format asks for it (above 16 bits or 2 channels)
    Auto,
    /// A plain WAVE_FORMAT_PCM header for any bits and channels (every reader opens it)
    Pcm,
    /// Always WAVE_FORMAT_EXTENSIBLE
    Extensible,
}

/// Refuses `path` early if it is a symbolic link, or exists without `force` (the race-free
/// refusal is [`create`]'s; this one comes before the broker is asked anything).
fn refuse_path(path: &Path, force: bool) -> Result<()> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => Err(symlink_refused(path)),
        Ok(_) if !force => Err(exists_refused(path)),
        _ => Ok(()),
    }
}

fn symlink_refused(path: &Path) -> anyhow::Error {
    Exit::new(
        exit::USAGE,
        format!(
            "{} is a symbolic link; bass record does not follow links (not even with --force): give the path of the file itself",
            path.display()
        ),
    )
    .into()
}

fn exists_refused(path: &Path) -> anyhow::Error {
    Exit::new(exit::USAGE, format!("{} exists; use --force to overwrite it", path.display())).into()
}

/// Creates `path` for writing: never through a symbolic link (O_NOFOLLOW), never over an
/// existing file unless `force` (O_EXCL).
fn create(path: &Path, force: bool) -> Result<File> {
    let mut o = OpenOptions::new();
    o.write(true).custom_flags(libc::O_NOFOLLOW);
    if force {
        o.create(true).truncate(true);
    } else {
        o.create_new(true);
    }
    match o.open(path) {
        Ok(f) => Ok(f),
        Err(e) if e.raw_os_error() == Some(libc::ELOOP) => Err(symlink_refused(path)),
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
            if std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink()) {
                Err(symlink_refused(path))
            } else {
                Err(exists_refused(path))
            }
        }
        Err(e) => Err(anyhow::Error::new(e).context(format!("create {}", path.display()))),
    }
}

/// Why the loop ended in failure.
enum Ended {
    /// Writing the WAV or the sidecar failed (a full disk): the file is kept, made consistent.
    Disk(io::Error),
    /// Anything else (the exit code is the error's).
    Other(anyhow::Error),
}

/// What one step of the loop did instead of reading frames.
enum Step {
    /// Nothing to read yet.
    Idle,
    /// The wait ended the acquisition's read (Stopped with nothing left, Restarted, ...).
    Wait(Error),
    /// A write failed.
    Disk(io::Error),
}

/// The checkpoints: every [`CHECKPOINT_EVERY`], or less often when the last one took more
/// than 1 / [`CHECKPOINT_SHARE`] of that (a long sidecar). The recorder flushes the WAV and
/// takes a snapshot of the sidecar; a thread writes the sidecar to a temporary file, patches
/// the header sizes to the snapshot's frames, and renames the sidecar into place, so the
/// reading never waits for a long sidecar.
struct Checkpoints {
    last: Instant,
    every: Duration,
    running: Option<std::thread::JoinHandle<io::Result<Duration>>>,
}

impl Checkpoints {
    fn new() -> Checkpoints {
        Checkpoints { last: Instant::now(), every: CHECKPOINT_EVERY, running: None }
    }

    /// Collects a finished checkpoint and starts the next one when it is due.
    fn poll(&mut self, rec: &mut Recording) -> io::Result<()> {
        if self.running.as_ref().is_some_and(|h| h.is_finished()) {
            self.wait()?;
        }
        if self.running.is_none() && self.last.elapsed() >= self.every {
            self.last = Instant::now();
            rec.wav.flush()?;
            let side = rec.sidecar(rec.wav.frames(), IN_PROGRESS, true);
            let data = side.recording.frames * rec.wav.spec().frame_bytes();
            let (file, format) = (rec.wav.file().try_clone()?, rec.wav.spec().format);
            let path = rec.side_path.clone();
            self.running = Some(std::thread::spawn(move || {
                let t0 = Instant::now();
                let tmp = stage(&path, &side)?;
                wav::patch_sizes(&file, format, data)?;
                std::fs::rename(&tmp, &path)?;
                Ok(t0.elapsed())
            }));
        }
        Ok(())
    }

    /// Waits for the checkpoint being written, if any.
    fn wait(&mut self) -> io::Result<()> {
        let Some(h) = self.running.take() else { return Ok(()) };
        let took = h.join().map_err(|_| io::Error::other("the checkpoint thread panicked"))??;
        self.every = CHECKPOINT_EVERY.max(took * CHECKPOINT_SHARE);
        tracing::debug!("checkpoint took {took:?}; the next in {:?}", self.every);
        Ok(())
    }
}

/// Writes `side` to a temporary file next to the sidecar `path`, to be renamed into place
/// (a reader or a kill sees the old sidecar or the new one, never half of one).
fn stage(path: &Path, side: &Sidecar) -> io::Result<PathBuf> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".{}.tmp", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let _ = std::fs::remove_file(&tmp);
    let r = OpenOptions::new()
        .write(true)
        .create_new(true)
        .custom_flags(libc::O_NOFOLLOW)
        .open(&tmp)
        .and_then(|mut f| f.write_all(&serde_json::to_vec_pretty(side)?));
    match r {
        Ok(()) => Ok(tmp),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// A recording in progress.
struct Recording {
    file: PathBuf,
    side_path: PathBuf,
    acquisition: sidecar::Acquisition,
    channels: Vec<u32>,
    /// The first frame asked for.
    requested: u64,
    /// The file's first frame, once a frame is in it.
    first: Option<u64>,
    /// The next frame to read.
    next: u64,
    rows: Vec<ChunkRow>,
    /// Frames of GAP rows in the file (for the progress line; the sidecar's is computed).
    gap_count: u64,
    losses: Vec<Lost>,
    wav: wav::Writer,
}

impl Recording {
    fn nfpc(&self) -> u64 {
        u64::from(self.acquisition.frames_per_chunk)
    }

    /// The last frame of the chunk holding `frame`.
    fn chunk_end(&self, frame: u64) -> u64 {
        ((frame - 1) / self.nfpc() + 1) * self.nfpc()
    }

    /// Waits for the rest of the chunk holding the next frame, then reads up to 4 chunks
    /// (never past the limit), so that every read but the first and the last ends on a chunk
    /// boundary and a loss (which starts at the frame asked for) starts on a chunk.
    fn step(&mut self, port: &Port, limit: Option<u64>, peaks: &mut [f64]) -> Result<(), Step> {
        let nfpc = self.nfpc();
        let lfi = match port.wait(self.chunk_end(self.next), Duration::from_millis(200)) {
            Ok(l) => l,
            Err(Error::Timeout { .. } | Error::Interrupted) => return Err(Step::Idle),
            Err(Error::Stopped { last }) if self.next <= last => last,
            Err(e) => return Err(Step::Wait(e)),
        };
        if lfi < self.next {
            return Err(Step::Idle);
        }
        let chunks = u64::from(self.acquisition.chunks_on_port / 2).clamp(1, 4);
        let mut end = lfi.min(self.chunk_end(self.next) + (chunks - 1) * nfpc);
        if let Some(l) = limit {
            end = end.min(self.first.unwrap_or(self.next) + l - 1);
        }
        // The chunk rows, read before the frames: a chunk whose frames the read then returns
        // intact had not been overwritten when its row was read, so its row is right.
        let before = self.next;
        let c0 = (before - 1) / nfpc;
        let pre: Vec<Option<ChunkRow>> = (c0..=(end - 1) / nfpc)
            .map(|c| {
                port.chunk_info((c * nfpc + 1).max(before)).ok().map(|ci| ChunkRow {
                    first_frame: ci.first_frame,
                    frames: ci.frames,
                    mono_ns: ci.mono_ns,
                    realtime_ns: ci.realtime_ns,
                    flags: ci.flags,
                })
            })
            .collect();
        let want = (end - before + 1) as usize;
        let used = *self.channels.iter().max().expect("channels") as usize + 1;
        let mut bufs = vec![vec![0i32; want]; used];
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| &mut b[..]).collect();
        let mut nfr = before;
        let r = port.get_audio_data(want, &mut nfr, &mut outs).map_err(Step::Wait)?;
        let got = before + r.loss; // the first frame delivered
                                   // Frames delivered past `end` (after a loss) are read again by the next step.
        let kept = if got <= end { (r.frames as u64).min(end - got + 1) } else { 0 };
        self.next = got + kept;
        if self.first.is_none() {
            // Frames lost before the first one in the file: not in the file, not a loss in it.
            if kept == 0 {
                return Ok(());
            }
            self.first = Some(got);
        } else if r.loss > 0 {
            let room = limit.map_or(u64::MAX, |l| l - self.wav.frames());
            let lost = r.loss.min(room);
            match self.losses.last_mut() {
                Some(l) if l.first_frame + l.frames == before => l.frames += lost,
                _ => self.losses.push(Lost { first_frame: before, frames: lost }),
            }
            for _ in 0..lost * self.channels.len() as u64 {
                self.wav.sample(0).map_err(Step::Disk)?;
            }
            if lost < r.loss {
                return Ok(()); // the limit
            }
        }
        let bits = self.wav.spec().bits;
        #[allow(clippy::needless_range_loop)] // interleaving: frame i of every selected channel
        for i in 0..kept as usize {
            for &c in &self.channels {
                self.wav.sample(convert(bufs[c as usize][i], bits)).map_err(Step::Disk)?;
            }
        }
        let lv = levels(
            &self.channels.iter().map(|&c| bufs[c as usize][..kept as usize].to_vec()).collect::<Vec<_>>(),
        );
        for (p, l) in peaks.iter_mut().zip(lv) {
            *p = p.max(l.1);
        }
        if kept > 0 {
            for c in (got - 1) / nfpc..=(got + kept - 2) / nfpc {
                if let Some(row) = pre[(c - c0) as usize] {
                    if row.first_frame == c * nfpc + 1
                        && self.rows.last().map_or(true, |p| p.first_frame < row.first_frame)
                    {
                        if row.flags & chunk_flags::GAP != 0 {
                            let from = row.first_frame.max(got);
                            self.gap_count += (row.first_frame + nfpc).min(got + kept) - from;
                        }
                        self.rows.push(row);
                    }
                }
            }
        }
        Ok(())
    }

    /// The sidecar of the first `frames` frames of the file.
    fn sidecar(&self, frames: u64, end: &str, in_progress: bool) -> Sidecar {
        let first = self.first.unwrap_or(self.next);
        let last = first + frames; // one past the file
        let losses: Vec<Lost> = self
            .losses
            .iter()
            .filter(|l| l.first_frame < last)
            .map(|l| Lost { first_frame: l.first_frame, frames: l.frames.min(last - l.first_frame) })
            .collect();
        let chunks: Vec<ChunkRow> = if frames == 0 {
            Vec::new()
        } else {
            self.rows.iter().filter(|r| r.first_frame < last).copied().collect()
        };
        let spec = self.wav.spec();
        let data = frames * spec.frame_bytes();
        let after = first - self.requested;
        let mut s = Sidecar {
            acquisition: self.acquisition.clone(),
            recording: sidecar::Recording {
                file: self.file.display().to_string(),
                first_frame: first,
                frames,
                seconds: frames as f64 / f64::from(self.acquisition.sample_rate),
                bytes: spec.format.header_len() + data + (data & 1),
                bits: spec.bits,
                channels: self.channels.clone(),
                gap_frames: 0,
                lost_frames: losses.iter().map(|l| l.frames).sum(),
                end: end.into(),
                requested_first_frame: (after > 0).then_some(self.requested),
                started_after_requested: after,
                wav_format: Some(spec.format.name().into()),
                in_progress,
            },
            losses,
            chunks,
        };
        s.recording.gap_frames = s.gap_frames_in_file();
        s
    }

    /// The first checkpoint (no frames yet), written to the sidecar just created.
    fn write_first_checkpoint(&self, mut f: File) -> io::Result<()> {
        f.write_all(&serde_json::to_vec_pretty(&self.sidecar(0, IN_PROGRESS, true))?)
    }

    /// Finalises the WAV and writes the final sidecar. If a write fails (a full disk), the
    /// WAV is cut to the whole frames that reached it, and if the sidecar does not fit, cut
    /// further by whole frames until it does. Returns the sidecar and the frames cut for it.
    fn finish(&mut self, end: &str) -> io::Result<(Sidecar, u64)> {
        let fb = self.wav.spec().frame_bytes();
        let mut frames = match self.wav.finalize() {
            Ok(n) => n,
            Err(_) => wav::repair(&self.file, fb, None)?,
        };
        let mut cut = 0;
        loop {
            let side = self.sidecar(frames, end, false);
            match stage(&self.side_path, &side).and_then(|tmp| std::fs::rename(tmp, &self.side_path)) {
                Ok(()) => return Ok((side, cut)),
                Err(e) if e.raw_os_error() == Some(libc::ENOSPC) && frames > 0 => {
                    // Free the sidecar's size and a few pages from the end of the WAV.
                    let need = serde_json::to_vec_pretty(&side).map_or(0, |v| v.len() as u64) + 8192;
                    let drop = need.div_ceil(fb).min(frames);
                    frames = wav::repair(&self.file, fb, Some(frames - drop))?;
                    cut += drop;
                }
                Err(e) => return Err(e),
            }
        }
    }
}

/// `bass record --check FILE.wav`: the one-line summary if the WAV and its sidecar agree,
/// else every problem found.
pub fn check(path: &Path) -> Result<String, Vec<String>> {
    let side = match Sidecar::load_for(path) {
        Ok(Some(s)) => s,
        Ok(None) => return Err(vec![format!("no sidecar {}", sidecar::path_of(path).display())]),
        Err(e) => return Err(vec![e]),
    };
    let mut f = File::open(path).map_err(|e| vec![format!("{}: {e}", path.display())])?;
    let info = wav::parse(&mut f).map_err(|e| vec![format!("{}: {e}", path.display())])?;
    let (a, r) = (&side.acquisition, &side.recording);
    let mut v = Vec::new();
    if info.sample_rate != a.sample_rate {
        v.push(format!("the WAV's rate is {} Hz; the sidecar's {}", info.sample_rate, a.sample_rate));
    }
    if usize::from(info.channels) != r.channels.len() {
        v.push(format!("the WAV has {} channels; the sidecar records {}", info.channels, r.channels.len()));
    }
    if info.bits != r.bits {
        v.push(format!("the WAV has {} bits per sample; the sidecar says {}", info.bits, r.bits));
    }
    let fb = u64::from(r.bits / 8) * r.channels.len() as u64;
    if u64::from(info.block_align) != fb {
        v.push(format!(
            "the WAV's block align is {}; {} channels of {} bits need {fb}",
            info.block_align,
            r.channels.len(),
            r.bits
        ));
    }
    let found = info.format().map_or(format!("format tag {:#x}", info.tag), |f| f.name().to_owned());
    if let Some(w) = &r.wav_format {
        if *w != found {
            v.push(format!("the WAV header is {found}; the sidecar says {w}"));
        }
    }
    let data = u64::from(info.data_size);
    if fb > 0 && data % fb != 0 {
        v.push(format!("the WAV's data chunk holds {data} bytes, not whole frames of {fb}"));
    }
    let frames = data.checked_div(fb).unwrap_or(0);
    if frames != r.frames {
        v.push(format!("the WAV holds {frames} frames; the sidecar says {}", r.frames));
    }
    let extent = info.data_offset + data + (data & 1);
    if extent != r.bytes {
        v.push(format!("the WAV's header describes {extent} bytes; the sidecar says {}", r.bytes));
    }
    if u64::from(info.riff_size) + 8 != extent {
        v.push(format!("the RIFF size is {}; the chunks take {}", info.riff_size, extent - 8));
    }
    if info.file_len < info.data_offset + data {
        v.push(format!("the file holds {} bytes; its header claims {extent}", info.file_len));
    } else if info.file_len > extent && !r.in_progress {
        v.push(format!("{} bytes after the data chunk", info.file_len - extent));
    }
    if (r.seconds - r.frames as f64 / f64::from(a.sample_rate.max(1))).abs() > 1e-6 {
        v.push(format!("recording.seconds {} is not frames / rate", r.seconds));
    }
    if v.is_empty() {
        v.extend(zeros_where_due(path, &side));
    }
    if !v.is_empty() {
        return Err(v);
    }
    let mut line = format!(
        "ok: {}: {} frames ({:.3} s), frames {}..={} of epoch {}, {} channels, {} bits, {found}; {} frames lost in {} losses, {} gap frames, {} chunk rows",
        path.display(),
        r.frames,
        r.seconds,
        r.first_frame,
        side.last_frame(),
        a.epoch,
        r.channels.len(),
        r.bits,
        r.lost_frames,
        side.losses.len(),
        r.gap_frames,
        side.chunks.len()
    );
    if let Some(q) = r.requested_first_frame {
        line += &format!("; started {} frames after the requested frame {q}", r.started_after_requested);
    }
    if r.in_progress {
        line += "; in progress: the last checkpoint of a recorder that did not finish (killed?)";
    }
    Ok(line)
}

/// The frames of losses and of GAP chunks must be zeros in the WAV.
fn zeros_where_due(path: &Path, side: &Sidecar) -> Vec<String> {
    let (first, last) = (side.recording.first_frame, side.last_frame());
    let mut runs: Vec<(u64, u64, &str)> =
        side.losses.iter().map(|l| (l.first_frame, l.first_frame + l.frames - 1, "lost")).collect();
    for c in side.chunks.iter().filter(|c| c.flags & chunk_flags::GAP != 0) {
        let (a, b) = (c.first_frame.max(first), (c.first_frame + u64::from(c.frames) - 1).min(last));
        if a <= b {
            runs.push((a, b, "GAP"));
        }
    }
    let mut r = match hound::WavReader::open(path) {
        Ok(r) => r,
        Err(e) => return vec![format!("hound cannot read {}: {e}", path.display())],
    };
    let ch = u64::from(r.spec().channels);
    let mut v = Vec::new();
    for (a, b, what) in runs {
        let Ok(at) = u32::try_from(a - first) else { continue };
        if let Err(e) = r.seek(at) {
            v.push(format!("seek to frame {a}: {e}"));
            continue;
        }
        let n = (b - a + 1) * ch;
        let nonzero = r.samples::<i32>().take(n as usize).position(|s| !matches!(s, Ok(0)));
        if let Some(i) = nonzero {
            v.push(format!(
                "{what} frame {} is not zero in the WAV (frames {a}..={b} must be)",
                a + i as u64 / ch
            ));
        }
    }
    v
}

/// Progress: an indicatif bar on a terminal, plain lines once per second otherwise.
struct Progress {
    bar: Option<indicatif::ProgressBar>,
    plain: bool,
    rate: u32,
}

impl Progress {
    fn new(quiet: bool, limit: Option<u64>, rate: u32) -> Progress {
        if quiet {
            return Progress { bar: None, plain: false, rate };
        }
        if std::io::stderr().is_terminal() {
            let bar = match limit {
                Some(n) => indicatif::ProgressBar::new(n),
                None => indicatif::ProgressBar::new_spinner(),
            };
            let style =
                indicatif::ProgressStyle::with_template("{elapsed_precise} {bar:30} {pos} frames {msg}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
            bar.set_style(style);
            Progress { bar: Some(bar), plain: false, rate }
        } else {
            Progress { bar: None, plain: true, rate }
        }
    }

    fn update(&self, frames: u64, bytes: u64, gaps: u64, lost: u64, peaks: &[f64]) {
        let levels: Vec<String> = peaks
            .iter()
            .enumerate()
            .map(|(c, p)| format!("ch{c} {}", dbfs(*p).map_or("-inf".into(), |d| format!("{d:.1}"))))
            .collect();
        let msg = format!(
            "{:.1} s, {:.1} MiB, gaps {gaps}, lost {lost}, peak dBFS {}",
            frames as f64 / f64::from(self.rate),
            bytes as f64 / 1048576.0,
            levels.join(" ")
        );
        if let Some(b) = &self.bar {
            b.set_position(frames);
            b.set_message(msg);
        } else if self.plain {
            eprintln!("bass record: {frames} frames, {msg}");
        }
    }

    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversion_rounds_half_up_and_saturates() {
        assert_eq!(convert(0x1234_5678, 32), 0x1234_5678);
        assert_eq!(convert(0x0001_8000, 16), 2); // 1.5 -> 2
        assert_eq!(convert(0x0001_7fff, 16), 1);
        assert_eq!(convert(-0x0001_8000, 16), -1); // -1.5 -> -1 (half up)
        assert_eq!(convert(i32::MAX, 16), i16::MAX as i32);
        assert_eq!(convert(i32::MIN, 16), i16::MIN as i32);
        assert_eq!(convert(i32::MAX, 24), (1 << 23) - 1);
        assert_eq!(convert(0x100 * 77 + 0x80, 24), 78);
    }

    #[test]
    fn from_accepts_oldest_now_and_frames() {
        assert_eq!(parse_from("oldest"), Ok(From::Oldest));
        assert_eq!(parse_from("now"), Ok(From::Now));
        assert_eq!(parse_from("12"), Ok(From::Frame(12)));
        assert!(parse_from("0").is_err() && parse_from("later").is_err());
    }

    /// A WAV of 400 frames (2 channels, 16 bits) from frame 151 with a loss of chunk 301..=400
    /// (zeros) and the sidecar that describes it; `poke` changes the pair before writing.
    fn pair(name: &str, poke: impl FnOnce(&mut Vec<i32>, &mut Sidecar)) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("bass-check-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r.wav");
        let mut samples: Vec<i32> = (151..551u64)
            .flat_map(|f| [0, 1].map(|c| if (301..=400).contains(&f) { 0 } else { (f * 2 + c) as i32 }))
            .collect();
        let row =
            |f: u64, flags: u32| ChunkRow { first_frame: f, frames: 100, mono_ns: f, realtime_ns: f, flags };
        let mut side: Sidecar = serde_json::from_value(serde_json::json!({
            "acquisition": {"device": "sim:pattern", "format": "S32_LE", "sample_rate": 8000, "channels": 2,
                            "frames_per_chunk": 100, "chunks_on_port": 20, "epoch": 1},
            "recording": {"file": "r.wav", "first_frame": 151, "frames": 400, "seconds": 0.05, "bytes": 44 + 1600,
                          "bits": 16, "channels": [0, 1], "gap_frames": 0, "lost_frames": 100, "end": "limit",
                          "wav_format": "pcm"},
            "losses": [{"first_frame": 301, "frames": 100}],
        }))
        .unwrap();
        side.chunks = vec![row(101, 0), row(201, 0), row(401, 0), row(501, 0)];
        poke(&mut samples, &mut side);
        let spec = wav::Spec { channels: 2, sample_rate: 8000, bits: 16, format: wav::Format::Pcm };
        let mut w = wav::Writer::new(File::create(&path).unwrap(), spec).unwrap();
        for s in samples {
            w.sample(s).unwrap();
        }
        w.finalize().unwrap();
        std::fs::write(sidecar::path_of(&path), serde_json::to_vec(&side).unwrap()).unwrap();
        path
    }

    #[test]
    fn check_accepts_a_pair_that_agrees_and_names_each_disagreement() {
        let done = |p: &Path| std::fs::remove_dir_all(p.parent().unwrap()).unwrap();
        let p = pair("ok", |_, _| {});
        let ok = check(&p).unwrap();
        done(&p);
        assert!(
            ok.starts_with("ok: ") && ok.contains("400 frames") && ok.contains("100 frames lost"),
            "{ok}"
        );
        type Poke = Box<dyn FnOnce(&mut Vec<i32>, &mut Sidecar)>;
        let cases: Vec<(&str, Poke, &str)> = vec![
            ("lost", Box::new(|s, _| s[(350 - 151) * 2] = 7), "lost frame 350 is not zero"),
            ("gap", Box::new(|_, d| d.chunks[3].flags = 1), "gap_frames is 0; the GAP chunks hold 50"),
            (
                "gapdata",
                Box::new(|_, d| {
                    d.chunks[3].flags = 1;
                    d.recording.gap_frames = 50;
                }),
                "GAP frame 501 is not zero",
            ),
            (
                "frames",
                Box::new(|s, _| s.truncate(399 * 2)),
                "the WAV holds 399 frames; the sidecar says 400",
            ),
            ("format", Box::new(|_, d| d.recording.wav_format = Some("extensible".into())), "header is pcm"),
            ("bits", Box::new(|_, d| d.recording.bits = 24), "16 bits per sample; the sidecar says 24"),
        ];
        for (name, poke, want) in cases {
            let path = pair(name, poke);
            let p = check(&path).unwrap_err();
            done(&path);
            assert!(p.iter().any(|m| m.contains(want)), "{name}: {want:?} not in {p:?}");
        }
        let p = check(Path::new("/nonexistent/r.wav")).unwrap_err();
        assert!(p[0].contains("no sidecar"), "{p:?}");
    }

    /// A port of 4 chunks of 10 frames (1 channel, sample = frame index) written in this
    /// process, and a recording of it from `from` into a WAV in `dir`.
    fn rig(dir: &Path, from: u64) -> (bassclient::Writer, Port, Recording) {
        use bassclient::{Geometry, PortParams};
        std::fs::create_dir_all(dir).unwrap();
        let geometry = Geometry { channels: 1, sample_rate: 8000, frames_per_chunk: 10, chunks_on_port: 4 };
        let path = dir.join("rec.port");
        let w = bassclient::Writer::create_at(
            &path,
            &PortParams { geometry, device: "unit".into(), group: None },
        )
        .unwrap();
        let port = Port::open_path(&path).unwrap();
        let file = dir.join("r.wav");
        let spec = wav::Spec { channels: 1, sample_rate: 8000, bits: 32, format: wav::Format::Pcm };
        let rec = Recording {
            side_path: sidecar::path_of(&file),
            wav: wav::Writer::new(File::create(&file).unwrap(), spec).unwrap(),
            file,
            acquisition: sidecar::Acquisition {
                device: "unit".into(),
                format: "S32_LE".into(),
                sample_rate: 8000,
                channels: 1,
                frames_per_chunk: 10,
                chunks_on_port: 4,
                epoch: port.epoch(),
            },
            channels: vec![0],
            requested: from,
            first: None,
            next: from,
            rows: Vec::new(),
            gap_count: 0,
            losses: Vec::new(),
        };
        (w, port, rec)
    }

    fn publish(w: &mut bassclient::Writer, chunks: u64) {
        for _ in 0..chunks {
            let lfi = w.last_frame_index();
            let s: Vec<i32> = (lfi + 1..=lfi + 10).map(|f| f as i32).collect();
            w.publish(bassclient::Source::Interleaved(&s), bassclient::ChunkMeta::default()).unwrap();
        }
    }

    fn samples(rec: &mut Recording) -> Vec<i32> {
        rec.wav.checkpoint().unwrap();
        hound::WavReader::open(&rec.file).unwrap().samples::<i32>().map(|s| s.unwrap()).collect()
    }

    #[test]
    fn reads_end_on_chunks_so_a_loss_starts_on_a_chunk_and_whole_chunks_have_rows() {
        let dir = std::env::temp_dir().join(format!("bass-rec-unit-{}-loss", std::process::id()));
        let (mut w, port, mut rec) = rig(&dir, 5);
        let mut peaks = [0.0];
        publish(&mut w, 3);
        // Frames 5..=20 (to the end of a chunk: at most 2 chunks a read with this window).
        assert!(rec.step(&port, None, &mut peaks).is_ok());
        assert_eq!((rec.first, rec.next), (Some(5), 21));
        // The port moves on by 10 chunks: frames 21..=90 are lost, from a chunk start.
        publish(&mut w, 10);
        while rec.next <= 130 {
            assert!(rec.step(&port, None, &mut peaks).is_ok());
        }
        assert_eq!(rec.losses, [Lost { first_frame: 21, frames: 70 }]);
        let rows: Vec<u64> = rec.rows.iter().map(|r| r.first_frame).collect();
        assert_eq!(rows, [1, 11, 91, 101, 111, 121], "a row for every chunk read, none for lost ones");
        let side = rec.sidecar(rec.wav.frames(), "limit", false);
        assert_eq!(side.problems(), Vec::<String>::new());
        assert_eq!((side.recording.first_frame, side.recording.frames), (5, 126));
        let want: Vec<i32> = (5..=130).map(|f| if (21..=90).contains(&f) { 0 } else { f }).collect();
        assert_eq!(samples(&mut rec), want);
        drop(port);
        w.remove().unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_start_the_port_no_longer_has_starts_the_file_at_its_oldest_chunk() {
        let dir = std::env::temp_dir().join(format!("bass-rec-unit-{}-late", std::process::id()));
        let (mut w, port, mut rec) = rig(&dir, 5);
        let mut peaks = [0.0];
        publish(&mut w, 13); // frames 91..=130 on the port
        while rec.next <= 130 {
            assert!(rec.step(&port, Some(25), &mut peaks).is_ok());
            if rec.wav.frames() == 25 {
                break;
            }
        }
        assert!(rec.losses.is_empty(), "no loss inside the file");
        let side = rec.sidecar(rec.wav.frames(), "limit", false);
        let r = &side.recording;
        assert_eq!(
            (r.first_frame, r.frames, r.requested_first_frame, r.started_after_requested),
            (91, 25, Some(5), 86)
        );
        assert_eq!(side.problems(), Vec::<String>::new());
        assert_eq!(
            samples(&mut rec),
            (91..116).collect::<Vec<i32>>(),
            "the limit counts from the file's start"
        );
        drop(port);
        w.remove().unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
