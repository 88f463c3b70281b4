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
use crate::follow::{after_stop, open_port, AfterStop};
use crate::wav;
use bassclient::args::parse_seconds;
use bassclient::sidecar;

mod check;
mod checkpoint;
mod files;
mod progress;
mod recording;

pub use check::check;
use checkpoint::Checkpoints;
use files::{create, refuse_path};
use progress::Progress;
use recording::{Ended, Recording, Step};

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

#[cfg(test)]
mod tests {
    use super::*;
    use bassclient::sidecar::{ChunkRow, Lost, Sidecar};
    use bassclient::Port;
    use std::fs::File;
    use std::path::Path;

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
