//! A recording in progress: the read loop's state, the rows, the losses, the end.

use std::fs::File;
use std::io::{self, Write};
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use bassport::format::chunk_flags;
use bassport::{Error, Port};

use crate::blocks::levels;
use crate::wav;
use basskit::sidecar::{self, ChunkRow, Lost, Sidecar};

use super::convert;
use super::mcap_out::McapOut;
use super::staged::{stage, IN_PROGRESS};
use super::xdf_out::XdfOut;

/// Why the loop ended in failure.
pub(super) enum Ended {
    /// Writing the WAV, its sidecar or the MCAP file failed (a full disk): the file is kept,
    /// made consistent.
    Disk(io::Error),
    /// Anything else (the exit code is the error's).
    Other(anyhow::Error),
}

/// How [`Recording::finish`] ended the file.
pub(super) struct Finished {
    /// The sidecar written (WAV), or the facts in the MCAP file.
    pub(super) side: Sidecar,
    /// Frames recorded but not kept: cut from the WAV to make room for its sidecar, or past
    /// the MCAP file's last checkpoint.
    pub(super) cut: u64,
    /// The write that failed while finishing (MCAP: the file was closed at its checkpoint).
    pub(super) error: Option<io::Error>,
}

/// What one step of the loop did instead of reading frames.
pub(super) enum Step {
    /// Nothing to read yet.
    Idle,
    /// The wait ended the acquisition's read (Stopped with nothing left, Restarted, ...).
    Wait(Error),
    /// A write failed.
    Disk(io::Error),
}

/// A recording in progress.
pub(super) struct Recording {
    pub(super) file: PathBuf,
    pub(super) side_path: PathBuf,
    pub(super) acquisition: sidecar::Acquisition,
    pub(super) channels: Vec<u32>,
    /// The first frame asked for.
    pub(super) requested: u64,
    /// The file's first frame, once a frame is in it.
    pub(super) first: Option<u64>,
    /// The next frame to read.
    pub(super) next: u64,
    pub(super) rows: Vec<ChunkRow>,
    /// Frames of GAP rows in the file (for the progress line; the sidecar's is computed).
    pub(super) gap_count: u64,
    pub(super) losses: Vec<Lost>,
    pub(super) out: Out,
}

/// Where the frames go.
pub(super) enum Out {
    /// A WAV file and its sidecar (lost frames as zeros).
    Wav(wav::Writer),
    /// An MCAP file in a bag directory (lost frames in no message).
    Mcap(Box<McapOut>),
    /// An XDF file (lost frames in no chunk, a marker each).
    Xdf(Box<XdfOut>),
}

impl Out {
    /// Frames in the file so far, lost ones included.
    pub(super) fn frames(&self) -> u64 {
        match self {
            Out::Wav(w) => w.frames(),
            Out::Mcap(m) => m.frames(),
            Out::Xdf(x) => x.frames(),
        }
    }

    /// Bytes per frame on the disk (the samples only).
    pub(super) fn frame_bytes(&self, channels: usize) -> u64 {
        match self {
            Out::Wav(w) => w.spec().frame_bytes(),
            Out::Mcap(_) | Out::Xdf(_) => 4 * channels as u64,
        }
    }
}

impl Recording {
    pub(super) fn nfpc(&self) -> u64 {
        u64::from(self.acquisition.frames_per_chunk)
    }

    /// The last frame of the chunk holding `frame`.
    pub(super) fn chunk_end(&self, frame: u64) -> u64 {
        ((frame - 1) / self.nfpc() + 1) * self.nfpc()
    }

    /// Waits for the rest of the chunk holding the next frame, then reads up to 4 chunks
    /// (never past the limit), so that every read but the first and the last ends on a chunk
    /// boundary and a loss (which starts at the frame asked for) starts on a chunk.
    pub(super) fn step(&mut self, port: &Port, limit: Option<u64>, peaks: &mut [f64]) -> Result<(), Step> {
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
        let pre = rows_of(port, before, end, nfpc);
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
            match &mut self.out {
                Out::Mcap(m) => m.begin(got),
                Out::Xdf(x) => x.begin(got),
                Out::Wav(_) => {}
            }
        } else if r.loss > 0 && !self.lose(before, r.loss, limit)? {
            return Ok(()); // the limit
        }
        self.write(&bufs, kept as usize, peaks)?;
        if kept > 0 {
            self.take_rows(&pre, (before - 1) / nfpc, got, kept);
        }
        match &mut self.out {
            Out::Mcap(m) => m.emit(&self.rows, false).map_err(Step::Disk)?,
            Out::Xdf(x) => x.emit(&self.rows, false).map_err(Step::Disk)?,
            Out::Wav(_) => {}
        }
        Ok(())
    }

    /// Records `loss` frames lost from `before` (zeros in a WAV, a loss in an MCAP file), at
    /// most up to the limit; whether the whole loss fitted.
    fn lose(&mut self, before: u64, loss: u64, limit: Option<u64>) -> Result<bool, Step> {
        let room = limit.map_or(u64::MAX, |l| l - self.out.frames());
        let lost = loss.min(room);
        match self.losses.last_mut() {
            Some(l) if l.first_frame + l.frames == before => l.frames += lost,
            _ => self.losses.push(Lost { first_frame: before, frames: lost }),
        }
        match &mut self.out {
            Out::Wav(w) => {
                for _ in 0..lost * self.channels.len() as u64 {
                    w.sample(0).map_err(Step::Disk)?;
                }
            }
            Out::Mcap(m) => m.lose(lost, &self.rows).map_err(Step::Disk)?,
            Out::Xdf(x) => x.lose(lost, &self.rows).map_err(Step::Disk)?,
        }
        Ok(lost == loss)
    }

    /// Writes the first `kept` frames of the selected channels of `bufs`, and raises `peaks`.
    fn write(&mut self, bufs: &[Vec<i32>], kept: usize, peaks: &mut [f64]) -> Result<(), Step> {
        #[allow(clippy::needless_range_loop)] // interleaving: frame i of every selected channel
        match &mut self.out {
            Out::Wav(w) => {
                let bits = w.spec().bits;
                for i in 0..kept {
                    for &c in &self.channels {
                        w.sample(convert(bufs[c as usize][i], bits)).map_err(Step::Disk)?;
                    }
                }
            }
            Out::Mcap(m) => {
                for i in 0..kept {
                    for &c in &self.channels {
                        m.push(bufs[c as usize][i]);
                    }
                }
            }
            Out::Xdf(x) => {
                for i in 0..kept {
                    for &c in &self.channels {
                        x.push(bufs[c as usize][i]);
                    }
                }
            }
        }
        let lv =
            levels(&self.channels.iter().map(|&c| bufs[c as usize][..kept].to_vec()).collect::<Vec<_>>());
        for (p, l) in peaks.iter_mut().zip(lv) {
            *p = p.max(l.1);
        }
        Ok(())
    }

    /// Keeps the rows (read before the frames, `pre[0]` the row of chunk `c0`) of the chunks
    /// whose frames `got .. got + kept` were delivered, each once, and counts their GAP frames.
    fn take_rows(&mut self, pre: &[Option<ChunkRow>], c0: u64, got: u64, kept: u64) {
        let nfpc = self.nfpc();
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

    /// The sidecar of the first `frames` frames of the file.
    pub(super) fn sidecar(&self, frames: u64, end: &str, in_progress: bool) -> Sidecar {
        let first = self.first.unwrap_or(self.next);
        let last = first + frames; // one past the file
        let losses: Vec<Lost> = self
            .losses
            .iter()
            .filter(|l| l.first_frame < last)
            .map(|l| Lost { first_frame: l.first_frame, frames: l.frames.min(last - l.first_frame) })
            .collect();
        // An MCAP recording's rows are its ChunkInfo messages: its facts (written every
        // checkpoint) keep only the GAP rows, for the gap count, not a copy of them all.
        let mcap = matches!(self.out, Out::Mcap(_) | Out::Xdf(_));
        let chunks: Vec<ChunkRow> = if frames == 0 {
            Vec::new()
        } else {
            let wanted = |r: &&ChunkRow| r.first_frame < last && (!mcap || r.flags & chunk_flags::GAP != 0);
            self.rows.iter().filter(wanted).copied().collect()
        };
        let (bits, bytes, wav_format) = match &self.out {
            Out::Wav(w) => {
                let spec = w.spec();
                let data = frames * spec.frame_bytes();
                (spec.bits, spec.format.header_len() + data + (data & 1), Some(spec.format.name().into()))
            }
            // The MCAP or XDF file's size is known once it is finished (set by `finish`).
            Out::Mcap(_) | Out::Xdf(_) => (32, 0, None),
        };
        let after = first - self.requested;
        let mut s = Sidecar {
            acquisition: self.acquisition.clone(),
            recording: sidecar::Recording {
                file: self.file.display().to_string(),
                first_frame: first,
                frames,
                seconds: frames as f64 / f64::from(self.acquisition.sample_rate),
                bytes,
                bits,
                channels: self.channels.clone(),
                gap_frames: 0,
                lost_frames: losses.iter().map(|l| l.frames).sum(),
                end: end.into(),
                requested_first_frame: (after > 0).then_some(self.requested),
                started_after_requested: after,
                wav_format,
                in_progress,
            },
            losses,
            chunks,
        };
        s.recording.gap_frames = s.gap_frames_in_file();
        s
    }

    /// The first checkpoint of an MCAP recording (no frames yet): from here on the file is a
    /// complete MCAP file.
    pub(super) fn write_first_mcap_checkpoint(&mut self) -> io::Result<()> {
        let side = self.sidecar(0, IN_PROGRESS, true);
        match &mut self.out {
            Out::Mcap(m) => m.checkpoint(&side),
            // An XDF file is complete (its magic and FileHeader) from its creation.
            Out::Wav(_) | Out::Xdf(_) => Ok(()),
        }
    }

    /// The first checkpoint (no frames yet), written to the sidecar just created.
    pub(super) fn write_first_checkpoint(&self, mut f: File) -> io::Result<()> {
        f.write_all(&serde_json::to_vec_pretty(&self.sidecar(0, IN_PROGRESS, true))?)
    }

    /// Finalises the WAV and writes the final sidecar, or finishes the MCAP file. If a write
    /// fails (a full disk), the WAV is cut to the whole frames that reached it, and if the
    /// sidecar does not fit, cut further by whole frames until it does; the MCAP file is closed
    /// at its last checkpoint. `disk_failed`: the recording ended on a failed write (`end` says
    /// which). Returns the sidecar (the MCAP file's facts) and how it ended.
    pub(super) fn finish(&mut self, end: &str, disk_failed: bool) -> io::Result<Finished> {
        if matches!(self.out, Out::Xdf(_)) {
            return self.finish_xdf(end, disk_failed);
        }
        if let Out::Mcap(m) = &self.out {
            let (frames, on_disk) = (m.frames(), m.frames_on_disk());
            let mut side = self.sidecar(frames, end, false);
            let Out::Mcap(m) = &mut self.out else { unreachable!("an MCAP recording") };
            let e = match m.finish(&self.rows, &side) {
                Ok(size) => {
                    side.recording.bytes = size;
                    return Ok(Finished { side, cut: 0, error: None });
                }
                Err(e) => e,
            };
            // The recording's end is the failure that ended it, else this one.
            let end = if disk_failed { end.to_owned() } else { e.to_string() };
            let mut side = self.sidecar(on_disk, &end, false);
            let Out::Mcap(m) = &mut self.out else { unreachable!("an MCAP recording") };
            side.recording.bytes = m.close_at_checkpoint(&side)?;
            return Ok(Finished { side, cut: frames - on_disk, error: Some(e) });
        }
        let Out::Wav(w) = &mut self.out else { unreachable!("MCAP and XDF recordings returned above") };
        let fb = w.spec().frame_bytes();
        let mut frames = match w.finalize() {
            Ok(n) => n,
            Err(_) => wav::repair(&self.file, fb, None)?,
        };
        let mut cut = 0;
        loop {
            let side = self.sidecar(frames, end, false);
            match stage(&self.side_path, &side).and_then(|tmp| std::fs::rename(tmp, &self.side_path)) {
                Ok(()) => return Ok(Finished { side, cut, error: None }),
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

impl Recording {
    /// [`Recording::finish`] of an XDF recording: the footers, or after a failed write the
    /// file closed at its last checkpoint.
    fn finish_xdf(&mut self, end: &str, disk_failed: bool) -> io::Result<Finished> {
        let Out::Xdf(x) = &mut self.out else { unreachable!("an XDF recording") };
        let (frames, on_disk) = (x.frames(), x.frames_on_disk());
        let e = match x.finish(&self.rows, end) {
            Ok(size) => {
                let mut side = self.sidecar(frames, end, false);
                side.recording.bytes = size;
                return Ok(Finished { side, cut: 0, error: None });
            }
            Err(e) => e,
        };
        // The recording's end is the failure that ended it, else this one.
        let end = if disk_failed { end.to_owned() } else { e.to_string() };
        let Out::Xdf(x) = &mut self.out else { unreachable!("an XDF recording") };
        let size = x.close_at_checkpoint(&end)?;
        let on_disk = on_disk.min(x.frames_on_disk());
        let mut side = self.sidecar(on_disk, &end, false);
        side.recording.bytes = size;
        Ok(Finished { side, cut: frames - on_disk, error: Some(e) })
    }
}

/// The rows of the chunks holding frames `before ..= end` (None where the port no longer has
/// one), read before the frames.
fn rows_of(port: &Port, before: u64, end: u64, nfpc: u64) -> Vec<Option<ChunkRow>> {
    ((before - 1) / nfpc..=(end - 1) / nfpc)
        .map(|c| port.chunk_info((c * nfpc + 1).max(before)).ok().map(|ci| ChunkRow::of(&ci)))
        .collect()
}
