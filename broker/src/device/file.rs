//! `sim:file:PATH.wav` (and `sim:file-loop:PATH.wav`): replays a WAV file as a capture device,
//! paced in real time like the other simulated devices, with the chunking of the Acquire.
//!
//! Samples are left-justified to S32 (a 32-bit recording made by `bass record` replays bit
//! for bit; a 16- or 24-bit one as its value shifted left; float as value × 2³¹, clipped).
//! If the sidecar `PATH.wav.json` written by `bass record` exists, its GAP chunks are
//! replayed as overruns: the device reports an xrun and skips those (zero) frames, so the
//! broker zero-fills them and flags the chunks GAP again, at the same frame indices when the
//! replay uses the recording's chunk size and the recording started on a chunk boundary.
//! The rate and channel count of the Acquire must be the file's: anything else is refused.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::time::Duration;

use bassclient::format::{chunk_flags, error_code};
use bassclient::sys::monotonic_ns;

use super::{Capture, ReadEvent, StopSignal};
use crate::os::{self, sleep_until_mono};

const NS_PER_MS: u64 = 1_000_000;

/// A WAV file replayed as a device.
pub struct FileDevice {
    path: PathBuf,
    reader: hound::WavReader<BufReader<File>>,
    spec: hound::WavSpec,
    looping: bool,
    rate: u64,
    channels: usize,
    period: usize,
    /// Frames in the file.
    total: u64,
    /// Next frame of the file (0-based).
    file_pos: u64,
    /// Device frames produced or skipped so far (paces the replay).
    pos: u64,
    start_ns: u64,
    /// GAP runs of the sidecar, as (first, frames) in file frames (0-based), sorted.
    gaps: Vec<(u64, u64)>,
}

/// Opens `path` for an Acquire at `rate` Hz with `channels` channels.
pub fn open(path: &Path, looping: bool, rate: u32, channels: u32, period: u32) -> Result<FileDevice, String> {
    let name = path.display();
    let reader = hound::WavReader::new(BufReader::new(open_regular(path)?))
        .map_err(|e| format!("sim:file:{name}: cannot read the WAV file: {e}"))?;
    let spec = reader.spec();
    if spec.sample_rate != rate || u32::from(spec.channels) != channels {
        return Err(format!(
            "sim:file:{name} holds {} Hz, {} channel(s); the Acquire asks for {rate} Hz, {channels} channel(s): use --rate {} --channels {}",
            spec.sample_rate, spec.channels, spec.sample_rate, spec.channels
        ));
    }
    let float_ok = spec.sample_format == hound::SampleFormat::Float && spec.bits_per_sample == 32;
    if spec.sample_format == hound::SampleFormat::Int && !(8..=32).contains(&spec.bits_per_sample)
        || !float_ok && spec.sample_format == hound::SampleFormat::Float
    {
        return Err(format!(
            "sim:file:{name}: {}-bit {:?} samples are not supported",
            spec.bits_per_sample, spec.sample_format
        ));
    }
    let total = u64::from(reader.duration());
    if total == 0 {
        return Err(format!("sim:file:{name} holds no frames"));
    }
    let gaps = sidecar_gaps(path);
    Ok(FileDevice {
        path: path.to_owned(),
        reader,
        spec,
        looping,
        rate: u64::from(rate),
        channels: channels as usize,
        period: period.max(1) as usize,
        total,
        file_pos: 0,
        pos: 0,
        start_ns: 0,
        gaps,
    })
}

/// Opens `path` for reading if it is a regular file, without ever blocking: a FIFO (or a
/// device node) would block `open` until someone writes to it, and with it the Acquire, every
/// later request and bassd's shutdown. The open is non-blocking (a FIFO opens at once), the
/// type is checked on the open descriptor (no race with a rename), then the descriptor is
/// made blocking again for the reads of a regular file.
fn open_regular(path: &Path) -> Result<File, String> {
    use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
    let name = path.display();
    let f = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32)
        .open(path)
        .map_err(|e| format!("sim:file:{name}: cannot read the WAV file: {e}"))?;
    let t = f.metadata().map_err(|e| format!("sim:file:{name}: {e}"))?.file_type();
    if !t.is_file() {
        let what = if t.is_fifo() {
            "a FIFO"
        } else if t.is_char_device() || t.is_block_device() {
            "a device node"
        } else if t.is_socket() {
            "a socket"
        } else {
            "not a regular file"
        };
        return Err(format!("sim:file:{name} is {what}: give a regular WAV file"));
    }
    rustix::fs::fcntl_setfl(&f, rustix::fs::OFlags::empty()).map_err(|e| format!("sim:file:{name}: {e}"))?;
    Ok(f)
}

/// The GAP chunks of the sidecar `PATH.json`, as runs of file frames (none without one).
fn sidecar_gaps(wav: &Path) -> Vec<(u64, u64)> {
    let mut p = wav.as_os_str().to_owned();
    p.push(".json");
    let Ok(bytes) = std::fs::read(&p) else { return Vec::new() };
    let Ok(v) = serde_json::from_slice::<serde_json::Value>(&bytes) else {
        tracing::warn!("sidecar {} is not JSON; replaying without its gaps", Path::new(&p).display());
        return Vec::new();
    };
    let first = v["recording"]["first_frame"].as_u64().unwrap_or(1).max(1);
    let mut runs: Vec<(u64, u64)> = Vec::new();
    for row in v["chunks"].as_array().into_iter().flatten() {
        let (Some(f), Some(n), Some(flags)) =
            (row["first_frame"].as_u64(), row["frames"].as_u64(), row["flags"].as_u64())
        else {
            continue;
        };
        if flags & u64::from(chunk_flags::GAP) == 0 || f < first {
            continue;
        }
        let start = f - first;
        match runs.last_mut() {
            Some((s, len)) if *s + *len == start => *len += n,
            _ => runs.push((start, n)),
        }
    }
    runs
}

impl FileDevice {
    fn due_ns(&self, k: u64) -> u64 {
        self.start_ns + (u128::from(k) * 1_000_000_000 / u128::from(self.rate)) as u64
    }

    /// Sleeps until `deadline`, returning false if the stop fired.
    fn sleep_until(&self, deadline: u64, stop: &StopSignal) -> bool {
        loop {
            if stop.is_set() {
                return false;
            }
            let now = monotonic_ns();
            if now >= deadline {
                return true;
            }
            let remaining = deadline - now;
            if remaining > 2 * NS_PER_MS {
                let mut fds = [os::pollin(stop.fd())];
                let _ = os::poll(&mut fds, Some(Duration::from_nanos(remaining - NS_PER_MS)));
            } else {
                sleep_until_mono(deadline);
            }
        }
    }

    /// Reads `n` frames of the file into `out` (interleaved, left-justified S32).
    fn fill(&mut self, out: &mut [i32], n: usize) -> Result<(), String> {
        let want = n * self.channels;
        let shift = 32 - u32::from(self.spec.bits_per_sample);
        let mut got = 0;
        if self.spec.sample_format == hound::SampleFormat::Float {
            for (o, s) in out[..want].iter_mut().zip(self.reader.samples::<f32>()) {
                let x = s.map_err(|e| e.to_string())?;
                *o = (f64::from(x) * 2_147_483_648.0).round().clamp(f64::from(i32::MIN), f64::from(i32::MAX))
                    as i32;
                got += 1;
            }
        } else {
            for (o, s) in out[..want].iter_mut().zip(self.reader.samples::<i32>()) {
                *o = s.map_err(|e| e.to_string())?.wrapping_shl(shift);
                got += 1;
            }
        }
        if got < want {
            return Err(format!("the file ended early ({got} of {want} samples)"));
        }
        self.file_pos += n as u64;
        Ok(())
    }

    fn rewind(&mut self) -> Result<(), String> {
        self.reader.seek(0).map_err(|e| e.to_string())?;
        self.file_pos = 0;
        Ok(())
    }

    fn failed(&self, what: &str) -> ReadEvent {
        ReadEvent::Failed {
            code: error_code::DEVICE_LOST,
            message: format!("sim:file:{}: {what}", self.path.display()),
        }
    }
}

impl Capture for FileDevice {
    fn start(&mut self) -> Result<(), String> {
        self.start_ns = monotonic_ns();
        Ok(())
    }

    fn read(&mut self, out: &mut [i32], max_frames: usize, stop: &StopSignal) -> ReadEvent {
        if self.file_pos >= self.total {
            if !self.looping {
                return ReadEvent::Ended {
                    message: format!(
                        "sim:file:{}: end of the recording after {} frames (replay ended)",
                        self.path.display(),
                        self.total
                    ),
                };
            }
            if let Err(e) = self.rewind() {
                return self.failed(&e);
            }
        }
        // A GAP run of the sidecar starting here: an overrun that skips its (zero) frames.
        if let Some(&(_, len)) = self.gaps.iter().find(|(s, _)| *s == self.file_pos) {
            let len = len.min(self.total - self.file_pos);
            if let Err(e) = self.reader.seek((self.file_pos + len) as u32) {
                return self.failed(&e.to_string());
            }
            self.file_pos += len;
            self.pos += len;
            return ReadEvent::Xrun;
        }
        let next_gap = self.gaps.iter().map(|(s, _)| *s).find(|s| *s > self.file_pos).unwrap_or(self.total);
        let n = max_frames
            .min(self.period)
            .min(out.len() / self.channels.max(1))
            .min((next_gap.min(self.total) - self.file_pos) as usize);
        let first = self.pos + 1;
        if !self.sleep_until(self.due_ns(self.pos + n as u64), stop) {
            return ReadEvent::Stopped;
        }
        let woke = monotonic_ns();
        if let Err(e) = self.fill(out, n) {
            return self.failed(&e);
        }
        let due = self.due_ns(self.pos + n as u64);
        let span = due - self.due_ns(self.pos);
        self.pos += n as u64;
        ReadEvent::Frames {
            frames: n,
            first_mono_ns: self.due_ns(first - 1),
            time_estimated: false,
            observed_mono_ns: woke.saturating_sub(span),
            // Woken well after the frames were due (the thread was starved): a catch-up read,
            // as the sim devices flag it.
            late: woke.saturating_sub(due) > span.max(1_000_000),
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
    fn a_rate_or_channel_mismatch_is_refused_with_the_files_values() {
        let dir = std::env::temp_dir().join(format!("bass-file-dev-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.wav");
        let spec = hound::WavSpec {
            channels: 2,
            sample_rate: 8000,
            bits_per_sample: 16,
            sample_format: hound::SampleFormat::Int,
        };
        let mut w = hound::WavWriter::create(&p, spec).unwrap();
        for i in 0..200 {
            w.write_sample(i as i16).unwrap();
        }
        w.finalize().unwrap();
        let e = open(&p, false, 48000, 2, 80).err().unwrap();
        assert!(e.contains("8000 Hz, 2 channel(s)") && e.contains("--rate 8000 --channels 2"), "{e}");
        assert!(open(&p, false, 8000, 1, 80).err().unwrap().contains("--channels 2"));
        let mut d = open(&p, false, 8000, 2, 80).unwrap();
        let mut out = vec![0; 20];
        d.fill(&mut out, 10).unwrap();
        assert_eq!(out[3], 3 << 16, "16-bit samples are left-justified");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_fifo_is_refused_at_once_without_blocking_in_open() {
        let dir = std::env::temp_dir().join(format!("bass-file-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("fifo.wav");
        rustix::fs::mknodat(
            rustix::fs::CWD,
            &p,
            rustix::fs::FileType::Fifo,
            rustix::fs::Mode::RUSR | rustix::fs::Mode::WUSR,
            0,
        )
        .unwrap();
        // With a blocking open this call never returns (nobody writes to the FIFO).
        let e = open(&p, false, 48000, 2, 480).err().expect("a FIFO is refused");
        assert!(e.contains("is a FIFO: give a regular WAV file"), "{e}");
        let e = open(Path::new("/dev/null"), false, 48000, 2, 480).err().expect("/dev/null is refused");
        assert!(e.contains("is a device node"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
