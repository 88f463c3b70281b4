//! `bass record --format xdf FILE` (the default for a FILE ending in `.xdf`): the recording as
//! one XDF 1.0 file (<https://github.com/sccn/xdf/wiki/Specifications>), the format of
//! LabRecorder, with the streams `bass lsl` publishes live ([`crate::labstream`]: the same
//! names, `desc`, stamps and marker JSON):
//!
//! - stream 1, the audio: type `Audio`, `int32` channels (the recorded ones), the port's
//!   nominal rate; one Samples chunk per run of frames in one port chunk, its first sample
//!   stamped with the chunk's CLOCK_MONOTONIC capture stamp plus the run's offset at the
//!   nominal rate ([`labstream::stamp_s`]), the others without a stamp (the spec's deduction:
//!   the previous stamp plus 1 / nominal rate); frames lost to the window are in no chunk
//!   (the next chunk's stamp jumps), zero-filled frames are samples (zeros);
//! - stream 2, the markers: type `Markers`, one `string` channel, irregular rate; one sample
//!   per loss (`overrun`) and per run of zero-filled frames (`gap`), the JSON of
//!   [`labstream::marker_json`], stamped at its first frame;
//! - ClockOffset chunks for both streams when the streams begin, every
//!   [`CLOCK_OFFSET_EVERY`] and at the end, offset 0: the stamps are this host's
//!   CLOCK_MONOTONIC already (a replica port's chunk table holds the source's stamps mapped to
//!   the local CLOCK_MONOTONIC by bass-bridge); Boundary chunks every [`BOUNDARY_EVERY`]; a
//!   StreamFooter per stream when the recording ends.
//!
//! Chunks reach the disk at the checkpoints (every second), whole, in one write at the end of
//! those on the disk: a recorder killed leaves a file of whole chunks without footers, which
//! XDF readers read (pyxdf does). A write that fails (a full disk) is cut back to the last
//! checkpoint, and the footers of what is on the disk are written if they fit.

use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use basskit::sidecar::ChunkRow;
use bassport::sys::{monotonic_ns, realtime_ns};
use bassport::Geometry;

use crate::labstream::{self, escape, zero_filled, Run, ZeroRuns, GAP, OVERRUN};

use super::files::create;
use super::recording::Out;
use super::RecordArgs;

/// The magic at the start of an XDF file.
pub const MAGIC: &[u8; 4] = b"XDF:";
/// The content of a Boundary chunk (the spec's UUID, which readers scan for after damage).
pub const BOUNDARY: [u8; 16] =
    [0x43, 0xA5, 0x46, 0xDC, 0xCB, 0xF5, 0x41, 0x0F, 0xB3, 0x0E, 0xD5, 0x46, 0x73, 0x83, 0xCB, 0xE4];
/// Chunk tags.
pub mod tag {
    /// FileHeader (XML).
    pub const FILE_HEADER: u16 = 1;
    /// StreamHeader (stream id, XML).
    pub const STREAM_HEADER: u16 = 2;
    /// Samples (stream id, samples).
    pub const SAMPLES: u16 = 3;
    /// ClockOffset (stream id, collection time, offset value).
    pub const CLOCK_OFFSET: u16 = 4;
    /// Boundary (16 bytes, [`super::BOUNDARY`]).
    pub const BOUNDARY: u16 = 5;
    /// StreamFooter (stream id, XML).
    pub const STREAM_FOOTER: u16 = 6;
}
/// The audio stream's id.
pub const AUDIO: u32 = 1;
/// The marker stream's id.
pub const MARKERS: u32 = 2;
/// How often ClockOffset chunks are written (LabRecorder's cadence).
pub const CLOCK_OFFSET_EVERY: Duration = Duration::from_secs(5);
/// How often a Boundary chunk is written (LabRecorder's cadence).
pub const BOUNDARY_EVERY: Duration = Duration::from_secs(10);

/// Whether `name` ends in `.xdf`.
pub fn is_xdf_name(name: &Path) -> bool {
    name.extension().is_some_and(|e| e.eq_ignore_ascii_case("xdf"))
}

/// An XDF variable-length integer: 1, 4 or 8 (one byte), then `n` in that many bytes (LE).
pub fn varlen(out: &mut Vec<u8>, n: u64) {
    if n < 256 {
        out.extend_from_slice(&[1, n as u8]);
    } else if let Ok(n) = u32::try_from(n) {
        out.push(4);
        out.extend_from_slice(&n.to_le_bytes());
    } else {
        out.push(8);
        out.extend_from_slice(&n.to_le_bytes());
    }
}

/// A chunk: its length (the tag and the content) as a variable-length integer, the tag (u16
/// LE), the content.
fn chunk(out: &mut Vec<u8>, tag: u16, content: &[u8]) {
    varlen(out, content.len() as u64 + 2);
    out.extend_from_slice(&tag.to_le_bytes());
    out.extend_from_slice(content);
}

/// The first and last stamp and the samples of a stream.
#[derive(Clone, Copy, Default)]
struct Stats {
    first: Option<f64>,
    last: f64,
    count: u64,
}

impl Stats {
    fn add(&mut self, first: f64, last: f64, n: u64) {
        self.first.get_or_insert(first);
        self.last = last;
        self.count += n;
    }
}

/// What is on the disk (at the last checkpoint): the footers describe it after a failure.
#[derive(Clone, Copy, Default)]
struct OnDisk {
    bytes: u64,
    frames: u64,
    headers: bool,
    stats: [Stats; 2],
    offsets: usize,
    lost: u64,
}

/// A recording being written as XDF.
pub struct XdfOut {
    file: File,
    path: PathBuf,
    /// Chunks not yet on the disk.
    buf: Vec<u8>,
    disk: OnDisk,
    broker: String,
    host: String,
    epoch: u64,
    geometry: Geometry,
    channels: Vec<u32>,
    rate: f64,
    nfpc: u64,
    /// Frames in the file so far (lost ones included).
    frames: u64,
    first: Option<u64>,
    headers: bool,
    /// Acquisition frame of the first frame of `pending`.
    pending_from: u64,
    /// Interleaved samples of frames not yet in a chunk.
    pending: Vec<i32>,
    /// A loss whose marker waits for the next stamp: first frame, frames.
    lost: Option<(u64, u64)>,
    lost_total: u64,
    last_row: Option<ChunkRow>,
    runs: ZeroRuns,
    stats: [Stats; 2],
    /// Collection times of the ClockOffset chunks written (offset 0 each).
    offsets: Vec<f64>,
    last_offset: Instant,
    last_boundary: Instant,
}

impl XdfOut {
    /// Starts the XDF file on `file` (created by the caller): the magic and the FileHeader,
    /// on the disk before it returns.
    pub fn new(
        file: File,
        path: &Path,
        broker: &str,
        geometry: &Geometry,
        epoch: u64,
        channels: &[u32],
    ) -> io::Result<XdfOut> {
        let mut x = XdfOut {
            file,
            path: path.to_owned(),
            buf: MAGIC.to_vec(),
            disk: OnDisk::default(),
            broker: broker.into(),
            host: labstream::hostname(),
            epoch,
            geometry: geometry.clone(),
            channels: channels.to_vec(),
            rate: f64::from(geometry.sample_rate.max(1)),
            nfpc: u64::from(geometry.frames_per_chunk.max(1)),
            frames: 0,
            first: None,
            headers: false,
            pending_from: 0,
            pending: Vec::new(),
            lost: None,
            lost_total: 0,
            last_row: None,
            runs: ZeroRuns::default(),
            stats: [Stats::default(); 2],
            offsets: Vec::new(),
            last_offset: Instant::now(),
            last_boundary: Instant::now(),
        };
        let header = format!(
            "<?xml version=\"1.0\"?><info><version>1.0</version><datetime>{}</datetime><writer>bass {}</writer></info>",
            iso8601(realtime_ns()),
            env!("CARGO_PKG_VERSION")
        );
        chunk(&mut x.buf, tag::FILE_HEADER, header.as_bytes());
        x.commit(&[])?;
        Ok(x)
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Frames in the file so far (lost ones included).
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Frames of the file on the disk: those of the last checkpoint.
    pub fn frames_on_disk(&self) -> u64 {
        self.disk.frames
    }

    /// The file's first frame is `first`: the stream headers (naming it) and the first
    /// ClockOffsets.
    pub fn begin(&mut self, first: u64) {
        self.pending_from = first;
        self.first = Some(first);
        self.stream_headers();
    }

    /// One frame's samples (the selected channels, in order).
    pub fn push(&mut self, s: i32) {
        self.pending.push(s);
        if self.pending.len() % self.channels.len() == 0 {
            self.frames += 1;
        }
    }

    /// `n` frames lost after the pending ones: those become chunks first; the loss's marker is
    /// written with the next chunk (stamped from its row) or at the end.
    pub fn lose(&mut self, n: u64, rows: &[ChunkRow]) -> io::Result<()> {
        self.emit(rows, true)?;
        if let Some(run) = self.runs.end() {
            self.gap_marker(run);
        }
        let from = self.pending_from;
        self.lost = match self.lost {
            Some((f, m)) if f + m == from => Some((f, m + n)),
            Some((f, m)) => {
                // Not seen: a loss follows the frames after the one before.
                let t = self.stamp_of(f, self.last_row);
                self.marker(f, m, OVERRUN, t);
                Some((from, n))
            }
            None => Some((from, n)),
        };
        self.pending_from += n;
        self.frames += n;
        Ok(())
    }

    /// Frames in the chunks made so far (from the file's first frame to the end of the last
    /// chunk, the losses whose markers are written included).
    fn frames_in_chunks(&self) -> u64 {
        self.first.map_or(0, |f| self.pending_from - f - self.lost.map_or(0, |l| l.1))
    }

    fn pending_frames(&self) -> u64 {
        (self.pending.len() / self.channels.len()) as u64
    }

    /// Makes a Samples chunk of every pending run that fills its port chunk (or every run,
    /// `all`), with the markers and the periodic chunks due.
    pub fn emit(&mut self, rows: &[ChunkRow], all: bool) -> io::Result<()> {
        while self.pending_frames() > 0 {
            let p0 = self.pending_from;
            let chunk0 = (p0 - 1) / self.nfpc * self.nfpc + 1;
            let to_end = chunk0 + self.nfpc - p0;
            let n = self.pending_frames().min(to_end);
            if n < to_end && !all {
                break;
            }
            let i = rows.partition_point(|r| r.first_frame < chunk0);
            let row = rows.get(i).filter(|r| r.first_frame == chunk0).copied();
            self.write_run(p0, n, row);
            self.pending.drain(..n as usize * self.channels.len());
            self.pending_from += n;
        }
        self.periodic();
        Ok(())
    }

    /// The stamp of `frame`: from `row` (its chunk's), else the last row at the nominal rate,
    /// else now (no row read yet: not seen).
    fn stamp_of(&self, frame: u64, row: Option<ChunkRow>) -> f64 {
        match row.or(self.last_row) {
            Some(r) => labstream::stamp_s(r.mono_ns, r.first_frame, frame, self.rate),
            None => monotonic_ns() as f64 / 1e9,
        }
    }

    fn write_run(&mut self, p0: u64, n: u64, row: Option<ChunkRow>) {
        if let Some((f, m)) = self.lost.take() {
            let t = self.stamp_of(f, row);
            self.marker(f, m, OVERRUN, t);
        }
        let flags = row.map_or(0, |r| r.flags);
        let nch = self.channels.len();
        for k in 0..n {
            let i = k as usize * nch;
            let zero = zero_filled(flags, self.pending[i..i + nch].iter().all(|&s| s == 0));
            let t = self.stamp_of(p0 + k, row);
            if let Some(run) = self.runs.frame(p0 + k, zero, || t) {
                self.gap_marker(run);
            }
        }
        let t0 = self.stamp_of(p0, row);
        if row.is_some() {
            self.last_row = row;
        }
        let mut c = Vec::with_capacity(16 + n as usize * (1 + 4 * nch));
        c.extend_from_slice(&AUDIO.to_le_bytes());
        varlen(&mut c, n);
        for k in 0..n as usize {
            if k == 0 {
                c.push(8);
                c.extend_from_slice(&t0.to_le_bytes());
            } else {
                c.push(0);
            }
            for s in &self.pending[k * nch..(k + 1) * nch] {
                c.extend_from_slice(&s.to_le_bytes());
            }
        }
        chunk(&mut self.buf, tag::SAMPLES, &c);
        self.stats[0].add(t0, t0 + (n - 1) as f64 / self.rate, n);
    }

    fn gap_marker(&mut self, run: Run) {
        self.marker(run.first_frame, run.frames, GAP, run.stamp);
    }

    /// One marker sample: `cause` for frames `first .. first + frames`, stamped `t`.
    fn marker(&mut self, first: u64, frames: u64, cause: &str, t: f64) {
        if cause == OVERRUN {
            self.lost_total += frames;
        }
        let text = labstream::marker_json(first, frames, cause, self.epoch);
        let mut c = MARKERS.to_le_bytes().to_vec();
        varlen(&mut c, 1);
        c.push(8);
        c.extend_from_slice(&t.to_le_bytes());
        varlen(&mut c, text.len() as u64);
        c.extend_from_slice(text.as_bytes());
        chunk(&mut self.buf, tag::SAMPLES, &c);
        self.stats[1].add(t, t, 1);
    }

    /// ClockOffsets and a Boundary when they are due.
    fn periodic(&mut self) {
        if self.headers && self.last_offset.elapsed() >= CLOCK_OFFSET_EVERY {
            self.clock_offsets();
        }
        if self.last_boundary.elapsed() >= BOUNDARY_EVERY {
            self.last_boundary = Instant::now();
            chunk(&mut self.buf, tag::BOUNDARY, &BOUNDARY);
        }
    }

    /// A ClockOffset chunk per stream: now, offset 0.
    fn clock_offsets(&mut self) {
        self.last_offset = Instant::now();
        let now = monotonic_ns() as f64 / 1e9;
        for id in [AUDIO, MARKERS] {
            let mut c = id.to_le_bytes().to_vec();
            c.extend_from_slice(&now.to_le_bytes());
            c.extend_from_slice(&0f64.to_le_bytes());
            chunk(&mut self.buf, tag::CLOCK_OFFSET, &c);
        }
        self.offsets.push(now);
    }

    /// The two StreamHeaders and the first ClockOffsets.
    fn stream_headers(&mut self) {
        let stream = labstream::stream_name(&self.broker);
        let source = labstream::source_id(&self.host, &self.broker);
        let mut desc = labstream::audio_desc(
            &self.broker,
            &self.host,
            self.epoch,
            &self.geometry,
            &self.channels,
            labstream::Clock::Monotonic,
        );
        let at = desc.iter().rposition(|(p, _)| p.starts_with("bass/")).map_or(desc.len(), |i| i + 1);
        let first = self.first.map_or_else(|| "none".to_owned(), |f| f.to_string());
        desc.insert(at, ("bass/first_frame".into(), first));
        let audio = self.info_xml(&stream, "Audio", self.channels.len(), self.rate, "int32", &source, &desc);
        let marker_name = labstream::marker_stream_name(&stream);
        let markers = self.info_xml(
            &marker_name,
            "Markers",
            1,
            0.0,
            "string",
            &format!("{source}:loss"),
            &labstream::marker_desc(&stream),
        );
        for (id, xml) in [(AUDIO, audio), (MARKERS, markers)] {
            let mut c = id.to_le_bytes().to_vec();
            c.extend_from_slice(xml.as_bytes());
            chunk(&mut self.buf, tag::STREAM_HEADER, &c);
        }
        self.headers = true;
        self.clock_offsets();
    }

    /// A stream's `<info>`, as LSL's (name, type, channel_count, channel_format, source_id,
    /// nominal_srate, version, created_at, uid, session_id, hostname, desc).
    #[allow(clippy::too_many_arguments)]
    fn info_xml(
        &self,
        name: &str,
        kind: &str,
        channels: usize,
        rate: f64,
        format: &str,
        source: &str,
        desc: &[(String, String)],
    ) -> String {
        format!(
            "<?xml version=\"1.0\"?><info><name>{}</name><type>{kind}</type><channel_count>{channels}</channel_count><channel_format>{format}</channel_format><source_id>{}</source_id><nominal_srate>{rate}</nominal_srate><version>1.1</version><created_at>{}</created_at><uid>{}</uid><session_id>default</session_id><hostname>{}</hostname>{}</info>",
            escape(name),
            escape(source),
            monotonic_ns() as f64 / 1e9,
            uid(),
            escape(&self.host),
            labstream::desc_xml(desc)
        )
    }

    /// The StreamFooters of `stats` and the first `offsets` ClockOffsets; `end` why the
    /// recording ended, `frames` and `lost` the audio's frames (lost ones included).
    fn footers(&self, stats: &[Stats; 2], offsets: usize, frames: u64, lost: u64, end: &str) -> Vec<u8> {
        let mut out = Vec::new();
        let clock: String = self.offsets[..offsets]
            .iter()
            .map(|t| format!("<offset><time>{t}</time><value>0</value></offset>"))
            .collect();
        for (k, id) in [AUDIO, MARKERS].into_iter().enumerate() {
            let s = stats[k];
            let bass = if id == AUDIO {
                format!(
                    "<bass><frames>{frames}</frames><lost_frames>{lost}</lost_frames><end>{}</end></bass>",
                    escape(end)
                )
            } else {
                String::new()
            };
            let xml = format!(
                "<?xml version=\"1.0\"?><info><first_timestamp>{}</first_timestamp><last_timestamp>{}</last_timestamp><sample_count>{}</sample_count><clock_offsets>{clock}</clock_offsets>{bass}</info>",
                s.first.unwrap_or(0.0),
                s.last,
                s.count
            );
            let mut c = id.to_le_bytes().to_vec();
            c.extend_from_slice(xml.as_bytes());
            chunk(&mut out, tag::STREAM_FOOTER, &c);
        }
        out
    }

    /// A checkpoint: the chunks made so far reach the disk. On an error the file is as it was.
    pub fn checkpoint(&mut self) -> io::Result<()> {
        self.commit(&[])
    }

    /// Writes the chunks not yet on the disk and `tail` after them, in one write at the end of
    /// the file; on an error the file is cut back to what it was (freeing what the failed
    /// write took) and nothing is counted as written.
    fn commit(&mut self, tail: &[u8]) -> io::Result<()> {
        let n = self.buf.len();
        self.buf.extend_from_slice(tail);
        let r = self.file.write_all_at(&self.buf, self.disk.bytes);
        if let Err(e) = r {
            self.buf.truncate(n);
            let _ = self.file.set_len(self.disk.bytes);
            return Err(e);
        }
        self.disk = OnDisk {
            bytes: self.disk.bytes + self.buf.len() as u64,
            frames: self.frames_in_chunks(),
            headers: self.headers,
            stats: self.stats,
            offsets: self.offsets.len(),
            lost: self.lost_total,
        };
        self.buf.clear();
        Ok(())
    }

    /// Writes the rest (the pending frames, the markers still open, the last ClockOffsets) and
    /// the footers; `end` is why the recording ended. Returns the file's size.
    pub fn finish(&mut self, rows: &[ChunkRow], end: &str) -> io::Result<u64> {
        self.emit(rows, true)?;
        if let Some(run) = self.runs.end() {
            self.gap_marker(run);
        }
        if let Some((f, m)) = self.lost.take() {
            let t = self.stamp_of(f, None);
            self.marker(f, m, OVERRUN, t);
        }
        if !self.headers {
            self.stream_headers();
        } else {
            self.clock_offsets();
        }
        let footers = self.footers(&self.stats, self.offsets.len(), self.frames, self.lost_total, end);
        self.commit(&footers)?;
        self.file.sync_all()?;
        Ok(self.disk.bytes)
    }

    /// After a failed write (a full disk): drops what is not on the disk and closes the file at
    /// the last checkpoint with the footers of what is there (`end` the recording's end), or
    /// without them if they do not fit. Returns the file's size.
    pub fn close_at_checkpoint(&mut self, end: &str) -> io::Result<u64> {
        self.buf.clear();
        self.headers = self.disk.headers;
        let d = self.disk;
        if d.headers {
            let footers = self.footers(&d.stats, d.offsets, d.frames, d.lost, end);
            // Best effort: the file is read without them.
            let _ = self.commit(&footers);
        }
        self.file.sync_all()?;
        Ok(self.file.metadata()?.len())
    }
}

/// Creates the XDF file of `a` for broker `name`'s port.
pub(super) fn open(a: &RecordArgs, name: &str, channels: &[u32], port: &bassport::Port) -> Result<Out> {
    let f = create(&a.file, a.force)?;
    let x = XdfOut::new(f, &a.file, name, port.geometry(), port.epoch(), channels)
        .with_context(|| format!("write {}", a.file.display()))?;
    Ok(Out::Xdf(Box::new(x)))
}

/// A random stream uid (the kernel's UUID source), or one from the pid and the clock.
fn uid() -> String {
    std::fs::read_to_string("/proc/sys/kernel/random/uuid")
        .map(|u| u.trim().to_owned())
        .unwrap_or_else(|_| format!("bass-{}-{}", std::process::id(), monotonic_ns()))
}

/// CLOCK_REALTIME `ns` as an ISO 8601 UTC time, `YYYY-MM-DDTHH:MM:SSZ`.
fn iso8601(ns: u64) -> String {
    let secs = ns / 1_000_000_000;
    let (days, rem) = ((secs / 86_400) as i64, secs % 86_400);
    // Days since 1970-01-01 to a civil date (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn varlen_uses_one_four_or_eight_bytes() {
        let enc = |n| {
            let mut v = Vec::new();
            varlen(&mut v, n);
            v
        };
        assert_eq!(enc(255), [1, 255]);
        assert_eq!(enc(256), [4, 0, 1, 0, 0]);
        assert_eq!(enc(1 << 32), [8, 0, 0, 0, 0, 1, 0, 0, 0]);
    }

    #[test]
    fn iso8601_of_known_instants() {
        assert_eq!(iso8601(0), "1970-01-01T00:00:00Z");
        assert_eq!(iso8601(951_782_400_000_000_000), "2000-02-29T00:00:00Z");
        assert_eq!(iso8601(1_700_000_000_123_000_000), "2023-11-14T22:13:20Z");
    }
}
