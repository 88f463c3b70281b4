//! `bass record FILE.wav`: reads the port losslessly (futex waits; a reader that keeps up
//! never loses frames) and writes a WAV file ([`super::wav`]) plus a sidecar `FILE.wav.json`
//! ([`bassclient::sidecar`]: the acquisition and one row per chunk — first frame,
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

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use bassclient::Error;

use crate::exit::{self, Exit};
use crate::follow::{after_stop, open_port, AfterStop, Outage};
use crate::out::{note, outln};
use crate::wav;
use bassclient::args::parse_seconds;
use bassclient::sidecar;

mod check;
mod checkpoint;
mod files;
pub mod mcap_out;
mod progress;
mod recording;

pub use check::check;
use checkpoint::Checkpoints;
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
    /// --format mcap, the bag directory to create (DIR/DIR_0.mcap and DIR/metadata.yaml)
    pub file: PathBuf,
    /// wav (WAV + JSON sidecar) or mcap (a rosbag2 bag directory: ROS 2 audio_common_msgs
    /// AudioDataStamped, AudioInfo and bass_msgs ChunkInfo messages, 32-bit samples)
    #[arg(long, value_name = "FORMAT", default_value = "wav")]
    pub format: OutFormat,
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

/// Runs `bass record` on broker `name` (or `bass record --check`).
pub fn run(name: &str, a: &RecordArgs, timeout: Duration) -> Result<()> {
    if a.check && (a.format == OutFormat::Mcap || a.file.is_dir()) {
        return Err(Exit::new(
            exit::USAGE,
            "--check verifies a WAV and its sidecar; an MCAP recording is checked when it is replayed (sim:file:DIR)",
        )
        .into());
    }
    if a.check {
        return match check(&a.file) {
            Ok(line) => {
                outln!("{line}")
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
    let mcap = a.format == OutFormat::Mcap;
    if mcap && a.bits != 32 {
        return Err(Exit::new(
            exit::USAGE,
            "--format mcap keeps the 32-bit samples as captured: leave out --bits",
        )
        .into());
    }
    let mcap_file = mcap_out::file_in(&a.file);
    let side_path = if mcap { mcap_file.clone() } else { sidecar::path_of(&a.file) };
    if mcap {
        refuse_path(&a.file, a.force)?;
    } else {
        for p in [&a.file, &side_path] {
            refuse_path(p, a.force)?;
        }
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
    let max_frames = if mcap {
        bassclient::format::MAX_FRAME_INDEX
    } else {
        (WAV_LIMIT - format.header_len()) / frame_bytes
    };
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
        note!(
            "bass record: waiting for frame {requested}; the port is at frame {lfi} ({:.1} s away at {} Hz)",
            (requested - lfi) as f64 / f64::from(g.sample_rate),
            g.sample_rate
        );
    }
    let (out, side_file) = if mcap {
        match std::fs::create_dir(&a.file) {
            Err(e) if !(a.force && e.kind() == std::io::ErrorKind::AlreadyExists && a.file.is_dir()) => {
                return Err(
                    anyhow::Error::new(e).context(format!("create the bag directory {}", a.file.display()))
                )
            }
            _ => {}
        }
        let f = create(&mcap_file, a.force)?;
        let m = mcap_out::McapOut::new(
            &a.file,
            f,
            name,
            channels.len(),
            g.sample_rate,
            g.frames_per_chunk,
            port.epoch(),
        )
        .with_context(|| format!("write {}", mcap_file.display()))?;
        (Out::Mcap(Box::new(m)), None)
    } else {
        let wav_file = create(&a.file, a.force)?;
        let side_file = match create(&side_path, a.force) {
            Ok(f) => f,
            Err(e) => {
                let _ = std::fs::remove_file(&a.file);
                return Err(e);
            }
        };
        let w = wav::Writer::new(wav_file, spec).with_context(|| format!("write {}", a.file.display()))?;
        (Out::Wav(w), Some(side_file))
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
    if let Some(f) = side_file {
        rec.write_first_checkpoint(f).with_context(|| format!("write {}", rec.side_path.display()))?;
    }
    let mut checkpoints = Checkpoints::new();
    let progress = Progress::new(a.quiet, limit, g.sample_rate);
    let mut peaks = vec![0f64; channels.len()];
    let mut last_progress = Instant::now();
    let mut outage = Outage::new(a.max_outage);
    let end: Result<String, Ended> = loop {
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
        let step = rec.step(&port, Some(limit.unwrap_or(max_frames)), &mut peaks);
        match (started, rec.first) {
            (false, Some(f)) if f > requested && !a.quiet => note!(
                "bass record: started {} frames after the requested frame {requested}, at frame {f} (the port no longer had the frames before it)",
                f - requested
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
                Error::Stopped { .. } => match after_stop(name, &port, timeout) {
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
        if let Err(e) = checkpoints.poll(&mut rec) {
            break Err(Ended::Disk(e));
        }
        if last_progress.elapsed() >= Duration::from_secs(1) {
            last_progress = Instant::now();
            let lost = rec.losses.iter().map(|l| l.frames).sum();
            let fb = rec.out.frame_bytes(channels.len());
            progress.update(rec.out.frames(), rec.out.frames() * fb, rec.gap_count, lost, &peaks);
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
    let said = if a.json {
        outln!("{}", serde_json::to_string(r)?)
    } else if !a.quiet && mcap {
        outln!(
            "recorded {} frames ({:.3} s) from frame {} to {}: {} bytes, {} gap frames, {} frames lost by the recorder; {}; bag directory {}",
            r.frames,
            r.seconds,
            r.first_frame,
            mcap_file.display(),
            r.bytes,
            r.gap_frames,
            r.lost_frames,
            r.end,
            a.file.display()
        )
    } else if !a.quiet {
        outln!(
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
        )
    } else {
        Ok(())
    };
    // The recording's own failure counts before a closed stdout.
    match failure {
        Some(Ended::Other(e)) => Err(e),
        _ => said,
    }
}

/// `--format`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutFormat {
    /// A WAV file and its JSON sidecar FILE.json
    Wav,
    /// A rosbag2 bag directory holding one MCAP file (ROS 2 messages, CDR)
    Mcap,
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
