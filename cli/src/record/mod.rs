//! `bass record FILE.wav`: reads the port losslessly (futex waits; a reader that keeps up
//! never loses frames) and writes a WAV file ([`super::wav`]) plus a sidecar `FILE.wav.json`
//! ([`basskit::sidecar`]: the acquisition and one row per chunk — first frame,
//! CLOCK_MONOTONIC / CLOCK_REALTIME ns, flags), so the recording can be aligned with the
//! robot's other sensors; and `bass record --check FILE.wav`, which verifies such a pair.
//!
//! WAV frame `i` is frame `first_frame + i` of the acquisition: frames the recorder lost
//! inside the file (the port overtook it) are written as zeros and listed in the sidecar, so
//! the recording is never silently shortened. Reads end on chunk boundaries, so such a loss
//! starts on a chunk. A start the port no longer had is not a loss: the file starts at the
//! first frame the port still had. The header and the sidecar are checkpointed together while
//! recording, and made to agree with what reached the disk when a write fails.
//! With `--format mcap` (or a FILE ending in `.mcap`) the same recording is one MCAP file of ROS 2
//! messages ([`mcap_out`]), complete at every checkpoint; `--check` verifies it too
//! ([`check_mcap`]); `--foxglove-audio` adds the same audio in 16 bits for Foxglove
//! ([`foxglove`]). With `--format xdf` (or a FILE ending in `.xdf`) it is one XDF file, the
//! streams `bass lsl` publishes ([`xdf_out`]), checked by [`check_xdf`]. See docs/broker.md for
//! the options, the rounding and what a kill loses.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use bassport::Error;

use crate::exit::{self, Exit};
use crate::follow::{after_stop, open_port, AfterStop, Outage};
use crate::out::{note, outln};
use crate::wav;
use basskit::args::parse_seconds;
use basskit::sidecar;

mod check;
mod check_mcap;
mod check_xdf;
mod checkpoint;
mod ending;
mod files;
mod foxglove;
pub mod mcap_out;
mod progress;
mod recording;
mod staged;
pub mod xdf_out;

pub use check::check;
pub use check_mcap::check_mcap;
pub use check_xdf::check_xdf;
use checkpoint::Checkpoints;
use ending::{close, summary};
use files::{create, refuse_path};
use progress::Progress;
use recording::{Ended, Out, Recording, Step};

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
    /// Output WAV file (the sidecar is FILE.json next to it, e.g. rec.wav.json); with
    /// --format mcap, the MCAP file if FILE ends in .mcap, else the bag directory to create
    /// (DIR/DIR_0.mcap and DIR/metadata.yaml)
    pub file: PathBuf,
    /// wav (WAV + JSON sidecar), mcap (ROS 2 audio_common_msgs AudioDataStamped, AudioInfo
    /// and bass_msgs ChunkInfo messages, 32-bit samples) or xdf (XDF 1.0: the audio and loss
    /// marker streams of `bass lsl`) [default: mcap for a FILE ending in .mcap, xdf for .xdf,
    /// else wav]
    #[arg(long, value_name = "FORMAT")]
    pub format: Option<OutFormat>,
    /// Verify FILE (a WAV and its sidecar, an MCAP recording: a .mcap file or a bag
    /// directory, or an XDF file) instead of recording (exit 0 and one "ok" line, else 1)
    #[arg(long)]
    pub check: bool,
    /// WAV header: auto (EXTENSIBLE above 16 bits or 2 channels), pcm (plain, for any
    /// reader) or extensible
    #[arg(long, value_name = "KIND", default_value = "auto")]
    pub wav_format: WavFormat,
    /// Bits per sample: 32 (as captured), 24 or 16 (rounded half up, saturating)
    #[arg(short = 'b', long, default_value_t = 32, value_parser = parse_bits)]
    pub bits: u16,
    /// With --format mcap: also each run as a foxglove_msgs/msg/RawAudio on
    /// /bass/<broker>/raw_audio (pcm-s16: the samples rounded to 16 bits as --bits 16 rounds
    /// them), the message Foxglove's Audio panel plays
    #[arg(long, conflicts_with = "check")]
    pub foxglove_audio: bool,
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
    /// End the recording when no frame comes for S seconds after a device error or a broker
    /// gone (a replica's link outage, a restart) [default: wait for the acquisition to go on]
    #[arg(long, value_name = "S", value_parser = parse_seconds)]
    pub max_outage: Option<f64>,
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

impl RecordArgs {
    /// The format: `--format`, else MCAP for a name ending in `.mcap`, XDF for `.xdf`.
    pub fn out_format(&self) -> OutFormat {
        self.format.unwrap_or(if mcap_out::is_mcap_name(&self.file) {
            OutFormat::Mcap
        } else if xdf_out::is_xdf_name(&self.file) {
            OutFormat::Xdf
        } else {
            OutFormat::Wav
        })
    }
}

/// Runs `bass record` on broker `name` (or `bass record --check`).
pub fn run(name: &str, a: &RecordArgs, timeout: Duration) -> Result<()> {
    if a.check {
        return run_check(a);
    }
    let format = a.out_format();
    let (mcap, xdf) = (format == OutFormat::Mcap, format == OutFormat::Xdf);
    refuse_for_format(a, format)?;
    let layout = mcap.then(|| mcap_out::Layout::of(&a.file));
    let side_path = match &layout {
        Some(l) => l.file().to_owned(),
        None if xdf => a.file.clone(),
        None => sidecar::path_of(&a.file),
    };
    refuse_path(&a.file, a.force)?;
    if !mcap && !xdf {
        refuse_path(&side_path, a.force)?;
    }
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&stop)).context("install the signal handlers")?;
    }
    let port = open_port(name, timeout, None)?;
    let (spec, channels) = spec_of(a, &port)?;
    let max_frames = if mcap || xdf {
        bassport::format::MAX_FRAME_INDEX
    } else {
        (WAV_LIMIT - spec.format.header_len()) / spec.frame_bytes()
    };
    let g = port.geometry().clone();
    let limit = match (a.frames, a.duration) {
        (Some(n), _) => Some(n),
        (None, Some(s)) => Some(((s * f64::from(g.sample_rate)).round() as u64).max(1)),
        (None, None) => None,
    };
    if let Some(n) = limit {
        if n > max_frames {
            return Err(Exit::new(exit::USAGE, format!(
                "{n} frames of {} bytes exceed the 4 GiB limit of a WAV file; record in several files (at most {max_frames} frames each)", spec.frame_bytes())).into());
        }
    }
    let (acquisition, requested) = start_of(name, a, &port, timeout)?;
    let (out, side_file) = match &layout {
        Some(l) => (open_mcap(a, l, name, channels.len(), &port)?, None),
        None if xdf => (xdf_out::open(a, name, &channels, &port)?, None),
        None => {
            let (w, f) = open_wav(a, &side_path, spec)?;
            (w, Some(f))
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
        out,
    };
    match side_file {
        Some(f) => rec.write_first_checkpoint(f),
        None => rec.write_first_mcap_checkpoint(),
    }
    .with_context(|| format!("write {}", rec.side_path.display()))?;
    let end = record_loop(name, a, &port, &mut rec, &stop, limit, max_frames, timeout);
    // Said once the file is closed, whatever stdout is.
    let (reason, failure) = match end {
        Ok(r) => (r, None),
        Err(Ended::Disk(e)) => (format!("{e}"), Some(Ended::Disk(e))),
        Err(Ended::Other(e)) => (format!("{e:#}"), Some(Ended::Other(e))),
    };
    let side = close(a, &mut rec, &reason, failure.as_ref(), layout.as_ref())?;
    let said = summary(a, &side.recording, &rec, layout.as_ref());
    // The recording's own failure counts before a closed stdout.
    match failure {
        Some(Ended::Other(e)) => Err(e),
        _ => said,
    }
}

/// The options `format` cannot honour: `--bits` but 32 for MCAP and XDF, `--foxglove-audio` but
/// for MCAP.
fn refuse_for_format(a: &RecordArgs, format: OutFormat) -> Result<()> {
    let (mcap, xdf) = (format == OutFormat::Mcap, format == OutFormat::Xdf);
    if (mcap || xdf) && a.bits != 32 {
        let f = if mcap { "mcap" } else { "xdf" };
        return Err(Exit::new(
            exit::USAGE,
            format!("--format {f} keeps the 32-bit samples as captured: leave out --bits {}", a.bits),
        )
        .into());
    }
    if a.foxglove_audio && !mcap {
        let f = if xdf { "xdf" } else { "wav" };
        return Err(Exit::new(
            exit::USAGE,
            format!("--foxglove-audio adds a channel to an MCAP recording: use --format mcap (or a FILE ending in .mcap), not --format {f}"),
        )
        .into());
    }
    Ok(())
}

/// The acquisition recorded (the port's, and the device format the broker reports) and the
/// first frame asked for; says on stderr when that frame is still ahead.
fn start_of(
    name: &str,
    a: &RecordArgs,
    port: &bassport::Port,
    timeout: Duration,
) -> Result<(sidecar::Acquisition, u64)> {
    let g = port.geometry();
    let info = port.info()?;
    let device_format = bassport::control::Client::connect(name)
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
        note!(
            "bass record: waiting for frame {requested}; the port is at frame {lfi} ({:.1} s away at {} Hz)",
            (requested - lfi) as f64 / f64::from(g.sample_rate),
            g.sample_rate
        );
    }
    Ok((acquisition, requested))
}

/// `bass record --check FILE`: a WAV and its sidecar, or an MCAP recording.
fn run_check(a: &RecordArgs) -> Result<()> {
    let format = a.out_format();
    let mcap = format == OutFormat::Mcap || a.file.is_dir();
    let xdf = format == OutFormat::Xdf && !mcap;
    let checked = if mcap {
        check_mcap(&a.file)
    } else if xdf {
        check_xdf(&a.file)
    } else {
        check(&a.file)
    };
    match checked {
        Ok(line) => outln!("{line}"),
        Err(problems) => {
            let what = if mcap {
                format!("{}: not a complete bass MCAP recording", a.file.display())
            } else if xdf {
                format!("{}: not a well-formed bass XDF recording", a.file.display())
            } else {
                format!("{} and its sidecar disagree", a.file.display())
            };
            Err(Exit::new(
                exit::FAILURE,
                format!("{what} ({} problems):\n  {}", problems.len(), problems.join("\n  ")),
            )
            .into())
        }
    }
}

/// The WAV format of the recording and the channels recorded.
fn spec_of(a: &RecordArgs, port: &bassport::Port) -> Result<(wav::Spec, Vec<u32>)> {
    let g = port.geometry();
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
    Ok((spec, channels))
}

/// Creates the MCAP file of `layout` (and its bag directory).
fn open_mcap(
    a: &RecordArgs,
    layout: &mcap_out::Layout,
    name: &str,
    channels: usize,
    port: &bassport::Port,
) -> Result<Out> {
    if let Some(dir) = layout.dir() {
        match std::fs::create_dir(dir) {
            Err(e) if !(a.force && e.kind() == std::io::ErrorKind::AlreadyExists && dir.is_dir()) => {
                return Err(
                    anyhow::Error::new(e).context(format!("create the bag directory {}", dir.display()))
                )
            }
            _ => {}
        }
    }
    let f = create(layout.file(), a.force)?;
    let g = port.geometry();
    let mut m =
        mcap_out::McapOut::new(layout, f, name, channels, g.sample_rate, g.frames_per_chunk, port.epoch())
            .with_context(|| format!("write {}", layout.file().display()))?;
    if a.foxglove_audio {
        m.add_raw_audio(name).with_context(|| format!("write {}", layout.file().display()))?;
    }
    Ok(Out::Mcap(Box::new(m)))
}

/// Creates the WAV file and its sidecar.
fn open_wav(a: &RecordArgs, side_path: &std::path::Path, spec: wav::Spec) -> Result<(Out, std::fs::File)> {
    let wav_file = create(&a.file, a.force)?;
    let side_file = match create(side_path, a.force) {
        Ok(f) => f,
        Err(e) => {
            let _ = std::fs::remove_file(&a.file);
            return Err(e);
        }
    };
    let w = wav::Writer::new(wav_file, spec).with_context(|| format!("write {}", a.file.display()))?;
    Ok((Out::Wav(w), side_file))
}

/// Reads the port into `rec` until a signal, a limit, the end of the acquisition or a failure;
/// checkpoints and progress on the way. Ok: why it ended.
#[allow(clippy::too_many_arguments)]
fn record_loop(
    name: &str,
    a: &RecordArgs,
    port: &bassport::Port,
    rec: &mut Recording,
    stop: &AtomicBool,
    limit: Option<u64>,
    max_frames: u64,
    timeout: Duration,
) -> Result<String, Ended> {
    let channels = rec.channels.len();
    let mut checkpoints = Checkpoints::new();
    let progress = Progress::new(a.quiet, limit, rec.acquisition.sample_rate);
    let mut peaks = vec![0f64; channels];
    let mut last_progress = Instant::now();
    let mut outage = Outage::new(a.max_outage);
    let end = loop {
        if stop.load(Ordering::Relaxed) {
            break Ok("signal".into());
        }
        let written = rec.out.frames();
        if limit.is_some_and(|l| written >= l) {
            break Ok("limit".into());
        }
        if written >= max_frames {
            break Ok(format!("file size limit reached at frame {}", rec.next - 1));
        }
        let started = rec.first.is_some();
        let step = rec.step(port, Some(limit.unwrap_or(max_frames)), &mut peaks);
        match (started, rec.first) {
            (false, Some(f)) if f > rec.requested && !a.quiet => note!(
                "bass record: started {} frames after the requested frame {}, at frame {f} (the port no longer had the frames before it)",
                f - rec.requested, rec.requested
            ),
            _ => {}
        }
        match step {
            Ok(()) => {
                if let Some(text) = outage.resumed() {
                    if !a.quiet {
                        note!("bass record: {text}");
                    }
                }
            }
            Err(Step::Idle) => {}
            Err(Step::Wait(e)) => match e {
                Error::Restarted => break Ok("a new acquisition started; the recording ends here".into()),
                Error::Stopped { .. } => match after_stop(name, port, timeout) {
                    Ok(AfterStop::Restarted) => {
                        break Ok("a new acquisition started; the recording ends here".into())
                    }
                    Ok(AfterStop::Stopped) => {
                        break Ok(format!("acquisition stopped at frame {}", rec.next - 1))
                    }
                    Err(e) => break Err(Ended::Other(e)),
                },
                e @ (Error::Device { .. } | Error::WriterGone { .. }) => match outage.pause(e, name) {
                    Ok(Some(text)) if !a.quiet => note!("bass record: {text}"),
                    Ok(_) => {}
                    Err(e) => break Err(Ended::Other(e)),
                },
                e => break Err(Ended::Other(e.into())),
            },
            Err(Step::Disk(e)) => break Err(Ended::Disk(e)),
        }
        if let Err(e) = checkpoints.poll(rec) {
            break Err(Ended::Disk(e));
        }
        if last_progress.elapsed() >= Duration::from_secs(1) {
            last_progress = Instant::now();
            let lost = rec.losses.iter().map(|l| l.frames).sum();
            let fb = rec.out.frame_bytes(channels);
            progress.update(rec.out.frames(), rec.out.frames() * fb, rec.gap_count, lost, &peaks);
            peaks.iter_mut().for_each(|p| *p = 0.0);
        }
    };
    progress.finish();
    // A checkpoint still being written: wait for it (it must not patch the final header);
    // its failure (a full disk) is handled by `finish` like any other.
    let _ = checkpoints.wait();
    end
}

/// `--format`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutFormat {
    /// A WAV file and its JSON sidecar FILE.json
    Wav,
    /// One MCAP file (ROS 2 messages, CDR): FILE.mcap, or a rosbag2 bag directory holding it
    Mcap,
    /// One XDF 1.0 file (LabRecorder's format): the audio stream and the loss marker stream
    Xdf,
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

#[cfg(test)]
mod tests;
