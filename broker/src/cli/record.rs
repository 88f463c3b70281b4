//! `bass record FILE.wav`: reads the port losslessly (futex waits; a reader that keeps up
//! never loses frames) and writes a WAV file with hound, plus a sidecar `FILE.wav.json` with
//! the acquisition and one row per chunk (first frame, CLOCK_MONOTONIC / CLOCK_REALTIME ns,
//! flags), so the recording can be aligned with the robot's other sensors.
//!
//! WAV sample `i` is frame `first_frame + i` of the acquisition: frames the recorder lost
//! (the port overtook it) are written as zeros and listed in the sidecar, so the recording
//! is never silently shortened. See docs/broker.md for the options and the rounding.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use bassclient::format::chunk_flags;
use bassclient::{Error, Port};
use serde::Serialize;

use super::blocks::{dbfs, levels};
use super::exit::{self, Exit};
use super::follow::{after_stop, open_port, AfterStop};
use crate::cli::parse_seconds;

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
    /// Overwrite FILE if it exists
    #[arg(long)]
    pub force: bool,
    /// No progress output
    #[arg(short = 'q', long)]
    pub quiet: bool,
    /// Print the summary as one JSON object
    #[arg(long)]
    pub json: bool,
}

/// One chunk of the recording in the sidecar.
#[derive(Serialize, Clone, Copy)]
struct ChunkRow {
    first_frame: u64,
    frames: u32,
    mono_ns: u64,
    realtime_ns: u64,
    flags: u32,
}

/// A run of frames the recorder lost (written as zeros).
#[derive(Serialize, Clone, Copy)]
struct Lost {
    first_frame: u64,
    frames: u64,
}

#[derive(Serialize)]
struct Acquisition {
    device: String,
    format: String,
    sample_rate: u32,
    channels: u32,
    frames_per_chunk: u32,
    chunks_on_port: u32,
    epoch: u64,
}

#[derive(Serialize)]
struct Summary {
    file: String,
    first_frame: u64,
    frames: u64,
    seconds: f64,
    bytes: u64,
    bits: u16,
    channels: Vec<u32>,
    gap_frames: u64,
    lost_frames: u64,
    end: String,
}

#[derive(Serialize)]
struct Sidecar<'a> {
    acquisition: &'a Acquisition,
    recording: &'a Summary,
    /// Frames the recorder lost (zeros in the WAV).
    losses: &'a [Lost],
    /// One row per chunk overlapping the recording; flags: 1 GAP, 2 DISCONTINUITY, 4 TIME_ESTIMATED.
    chunks: &'a [ChunkRow],
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

/// Runs `bass record` on broker `name`.
pub fn run(name: &str, a: &RecordArgs, timeout: Duration) -> Result<()> {
    if a.file.exists() && !a.force {
        return Err(Exit::new(
            exit::USAGE,
            format!("{} exists; use --force to overwrite it", a.file.display()),
        )
        .into());
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
    let frame_bytes = u64::from(a.bits / 8) * channels.len() as u64;
    let limit = match (a.frames, a.duration) {
        (Some(n), _) => Some(n),
        (None, Some(s)) => Some(((s * f64::from(g.sample_rate)).round() as u64).max(1)),
        (None, None) => None,
    };
    if let Some(n) = limit {
        if n.saturating_mul(frame_bytes) > WAV_LIMIT {
            return Err(Exit::new(exit::USAGE, format!(
                "{n} frames of {frame_bytes} bytes exceed the 4 GiB limit of a WAV file; record in several files (at most {} frames each)",
                WAV_LIMIT / frame_bytes)).into());
        }
    }
    let info = port.info()?;
    let format = bassclient::control::Client::connect(name)
        .and_then(|mut c| {
            c.set_timeout(timeout)?;
            c.status()
        })
        .map(|s| s.format)
        .unwrap_or_default();
    let acq = Acquisition {
        device: info.device.clone(),
        format,
        sample_rate: g.sample_rate,
        channels: g.channels,
        frames_per_chunk: g.frames_per_chunk,
        chunks_on_port: g.chunks_on_port,
        epoch: port.epoch(),
    };
    let spec = hound::WavSpec {
        channels: channels.len() as u16,
        sample_rate: g.sample_rate,
        bits_per_sample: a.bits,
        sample_format: hound::SampleFormat::Int,
    };
    let mut wav =
        hound::WavWriter::create(&a.file, spec).with_context(|| format!("create {}", a.file.display()))?;
    let lfi = info.last_frame_index;
    let first = match a.from {
        From::Now => lfi + 1,
        From::Oldest => (lfi + 1).saturating_sub(port.frames_on_port()).max(1),
        From::Frame(f) => f,
    };
    let nfpc = u64::from(g.frames_per_chunk);
    let cap = (nfpc * 4).min(port.frames_on_port().max(1) / 2).max(1) as usize;
    let mut bufs = vec![vec![0i32; cap]; g.channels as usize];
    let (mut nfr, mut written, mut gap_frames) = (first, 0u64, 0u64);
    let mut rows: Vec<ChunkRow> = Vec::new();
    let mut losses: Vec<Lost> = Vec::new();
    let mut next_chunk = (first - 1) / nfpc; // the next chunk whose row is due
    let progress = Progress::new(a.quiet, limit, g.sample_rate);
    let mut last_flush = Instant::now();
    let max_frames = WAV_LIMIT / frame_bytes;
    let mut peaks = vec![0f64; channels.len()];
    let end: Result<String> = loop {
        let want = limit.map_or(cap as u64, |l| (l - written).min(cap as u64)) as usize;
        if want == 0 {
            break Ok("limit".into());
        }
        if written + want as u64 > max_frames {
            break Ok(format!("4 GiB WAV limit reached at frame {}", nfr - 1));
        }
        if stop.load(Ordering::Relaxed) {
            break Ok("signal".into());
        }
        match port.wait(nfr + want.min(nfpc as usize) as u64 - 1, Duration::from_millis(200)) {
            Ok(_) | Err(Error::Timeout { .. }) | Err(Error::Interrupted) => {}
            Err(Error::Restarted) => break Ok("a new acquisition started; the recording ends here".into()),
            Err(Error::Stopped { last }) => {
                if nfr <= last {
                    // Frames left to read before the end.
                } else {
                    break Ok(match after_stop(name, &port, timeout)? {
                        AfterStop::Restarted => "a new acquisition started; the recording ends here".into(),
                        AfterStop::Stopped => format!("acquisition stopped at frame {last}"),
                    });
                }
            }
            Err(Error::Device { code, message }) => {
                break Err(Exit::new(
                    exit::DEVICE_ENDED,
                    format!("the acquisition ended on a device error (code {code}): {message}"),
                )
                .into())
            }
            Err(e @ Error::WriterGone { .. }) => break Err(Exit::new(exit::NO_BROKER, e.to_string()).into()),
            Err(e) => break Err(e.into()),
        }
        let before = nfr;
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| &mut b[..want]).collect();
        let r = port.get_audio_data(want, &mut nfr, &mut outs)?;
        if r.loss > 0 {
            // Keep WAV index = frame index: the lost frames become zeros, listed in the sidecar.
            let lost = r.loss.min(limit.map_or(u64::MAX, |l| l - written));
            losses.push(Lost { first_frame: before, frames: r.loss });
            for _ in 0..lost * channels.len() as u64 {
                wav.write_sample(0i32)?;
            }
            written += lost;
        }
        let n = r.frames.min(limit.map_or(usize::MAX, |l| (l - written) as usize));
        #[allow(clippy::needless_range_loop)] // interleaving: frame i of every selected channel
        for i in 0..n {
            for &c in &channels {
                wav.write_sample(convert(bufs[c as usize][i], a.bits))?;
            }
        }
        written += n as u64;
        let lv = levels(&channels.iter().map(|&c| bufs[c as usize][..n].to_vec()).collect::<Vec<_>>());
        for (p, l) in peaks.iter_mut().zip(lv) {
            *p = p.max(l.1);
        }
        // Rows of the chunks read completely so far (while they are still on the port).
        while (next_chunk + 1) * nfpc < first + written {
            gap_frames += chunk_row(&port, next_chunk, first, first + written - 1, &mut rows);
            next_chunk += 1;
        }
        if last_flush.elapsed() >= Duration::from_secs(1) {
            // A flushed WAV is valid as it stands, even if the recorder is killed later.
            wav.flush()?;
            last_flush = Instant::now();
            progress.update(
                written,
                written * frame_bytes,
                gap_frames,
                losses.iter().map(|l| l.frames).sum(),
                &peaks,
            );
            peaks.iter_mut().for_each(|p| *p = 0.0);
        }
    };
    if next_chunk * nfpc < first + written - 1 {
        // The last chunk, read in part.
        gap_frames += chunk_row(&port, next_chunk, first, first + written - 1, &mut rows);
    }
    wav.finalize().with_context(|| format!("finalise {}", a.file.display()))?;
    progress.finish();
    let lost_frames = losses.iter().map(|l| l.frames).sum();
    let summary = Summary {
        file: a.file.display().to_string(),
        first_frame: first,
        frames: written,
        seconds: written as f64 / f64::from(g.sample_rate),
        bytes: std::fs::metadata(&a.file).map(|m| m.len()).unwrap_or(0),
        bits: a.bits,
        channels,
        gap_frames,
        lost_frames,
        end: match &end {
            Ok(s) => s.clone(),
            Err(e) => format!("{e:#}"),
        },
    };
    let sidecar = Sidecar { acquisition: &acq, recording: &summary, losses: &losses, chunks: &rows };
    let side = sidecar_path(&a.file);
    std::fs::write(&side, serde_json::to_vec_pretty(&sidecar)?)
        .with_context(|| format!("write {}", side.display()))?;
    if a.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else if !a.quiet {
        println!(
            "recorded {} frames ({:.3} s) from frame {first} to {}: {} bytes, {} gap frames, {lost_frames} frames lost by the recorder; {}; sidecar {}",
            written,
            summary.seconds,
            a.file.display(),
            summary.bytes,
            gap_frames,
            summary.end,
            side.display()
        );
    }
    end.map(|_| ())
}

/// Adds the row of chunk `chunk` (0-based) to `rows` if it is still on the port; returns the
/// gap frames it holds within the recording `first..=last`.
fn chunk_row(port: &Port, chunk: u64, first: u64, last: u64, rows: &mut Vec<ChunkRow>) -> u64 {
    let nfpc = u64::from(port.geometry().frames_per_chunk);
    let (from, to) = ((chunk * nfpc + 1).max(first), ((chunk + 1) * nfpc).min(last));
    let Ok(ci) = port.chunk_info(from) else { return 0 };
    rows.push(ChunkRow {
        first_frame: ci.first_frame,
        frames: ci.frames,
        mono_ns: ci.mono_ns,
        realtime_ns: ci.realtime_ns,
        flags: ci.flags,
    });
    if ci.flags & chunk_flags::GAP != 0 && to >= from {
        to - from + 1
    } else {
        0
    }
}

/// `FILE.wav` → `FILE.wav.json`.
pub fn sidecar_path(wav: &Path) -> PathBuf {
    let mut s = wav.as_os_str().to_owned();
    s.push(".json");
    PathBuf::from(s)
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
}
