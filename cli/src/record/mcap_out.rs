//! `bass record --format mcap NAME`: the recording as one MCAP file — `NAME` itself when it ends
//! in `.mcap`, else a rosbag2 bag directory `NAME/` holding `NAME/<name>_0.mcap` and
//! `NAME/metadata.yaml` (`<name>` the directory's own name).
//!
//! The MCAP file (profile `ros2`, chunked, uncompressed, as rosbag2's MCAP plugin writes by
//! default) holds three channels (four on request), each with a `ros2msg` schema and CDR messages from
//! [`basskit::ros2`]:
//!
//! - `/bass/<broker>/audio_info`: one `audio_common_msgs/msg/AudioInfo`;
//! - `/bass/<broker>/chunk_info`: per run of frames (a port chunk, or its part in the file), a
//!   `bass_msgs/msg/ChunkInfo` with the frame index, frames, flags, both clocks and the loss
//!   before it;
//! - `/bass/<broker>/audio`: the same run's `AudioDataStamped`, interleaved S32LE, written just
//!   after its ChunkInfo with the same MCAP sequence number and log time;
//! - with `--foxglove-audio`, `/bass/<broker>/raw_audio`: the same run as a
//!   `foxglove_msgs/msg/RawAudio` in `pcm-s16`, written just after the audio message with the
//!   same sequence number, log time and stamp ([`super::foxglove`]).
//!
//! Frames the recorder lost are in no message (never zeros presented as audio): the next
//! ChunkInfo's `lost_before` counts them. A metadata record `bass` holds the sidecar's file-level
//! facts (acquisition, recording, losses: `basskit::sidecar` without the rows, which are the
//! ChunkInfo messages). `metadata.yaml` is there for rosbag2 releases that open only a bag
//! directory (`ros2 bag play DIR`); the MCAP file alone is complete for every other reader.
//!
//! The file is a readable MCAP file at every checkpoint, as a WAV recording is: the writer's
//! records reach the disk only at a checkpoint (every second, after the chunk being written
//! is closed), followed by a tail — the `bass` metadata record of the frames on the disk
//! (`in_progress`), a DataEnd and a Footer without a summary, and the closing magic — that the
//! next checkpoint writes over. A recorder killed leaves the last checkpoint: every reader reads
//! it front to back (PyPI `mcap` falls back to that without a summary), `bass record --check`
//! passes it and bassd replays it. A write that fails (a full disk, ENOSPC) is cut back to the
//! last checkpoint and the tail is written again with the recording's end: the file keeps the
//! frames of that checkpoint.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, Seek, SeekFrom, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::rc::Rc;

use basskit::ros2::foxglove::RAW_AUDIO;
use basskit::ros2::{self, AudioDataStamped, AudioInfo, ChunkInfo, Header, Time, Topics};
use basskit::sidecar::{ChunkRow, Sidecar};

use super::foxglove;

/// Name of the metadata record holding the sidecar's facts.
pub const METADATA_NAME: &str = "bass";
/// Its key holding them as JSON (a `basskit::sidecar::Sidecar` without chunk rows).
pub const METADATA_SIDECAR: &str = "sidecar";

/// QoS offered (rosbag2's `offered_qos_profiles`, the integer form every rosbag2 release reads):
/// reliable, volatile, keep last 100, for the audio and chunk topics.
pub(super) const QOS_STREAM: &str = "- history: 1\n  depth: 100\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 9223372036\n    nsec: 854775807\n  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n  avoid_ros_namespace_conventions: false\n";
/// For AudioInfo: transient local, so a subscriber that joins late still gets it.
const QOS_LATCHED: &str = "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n  deadline:\n    sec: 9223372036\n    nsec: 854775807\n  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n  avoid_ros_namespace_conventions: false\n";

/// The magic at both ends of an MCAP file.
const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

fn mcap_err(e: mcap::McapError) -> io::Error {
    match e {
        // The OS error itself (ENOSPC is "No space left on device"), not mcap's wrapper text.
        mcap::McapError::Io(e) => e,
        e => io::Error::other(e.to_string()),
    }
}

/// The MCAP file of a bag directory `dir`.
pub fn file_in(dir: &Path) -> PathBuf {
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "bass".into());
    dir.join(format!("{name}_0.mcap"))
}

/// Where `bass record --format mcap NAME` writes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Layout {
    /// `NAME` ends in `.mcap`: that one file.
    File(PathBuf),
    /// A rosbag2 bag directory and its MCAP file ([`file_in`]).
    Bag {
        /// The directory.
        dir: PathBuf,
        /// The MCAP file in it.
        file: PathBuf,
    },
}

impl Layout {
    /// The layout for the name given on the command line.
    pub fn of(name: &Path) -> Layout {
        if is_mcap_name(name) {
            Layout::File(name.to_owned())
        } else {
            Layout::Bag { dir: name.to_owned(), file: file_in(name) }
        }
    }

    /// The MCAP file.
    pub fn file(&self) -> &Path {
        match self {
            Layout::File(f) | Layout::Bag { file: f, .. } => f,
        }
    }

    /// The bag directory, if any.
    pub fn dir(&self) -> Option<&Path> {
        match self {
            Layout::File(_) => None,
            Layout::Bag { dir, .. } => Some(dir),
        }
    }
}

/// Whether `name` ends in `.mcap` (then it names an MCAP file, not a bag directory).
pub fn is_mcap_name(name: &Path) -> bool {
    name.extension().is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}

/// What the MCAP writer writes: kept in memory until [`McapOut::checkpoint`] puts it on the
/// disk. It only appends; its position is the writer's offset in the file.
#[derive(Clone, Default)]
struct Sink(Rc<RefCell<Pending>>);

#[derive(Default)]
struct Pending {
    /// Bytes of the writer's records before `bytes` (on the disk).
    offset: u64,
    bytes: Vec<u8>,
}

impl Write for Sink {
    fn write(&mut self, b: &[u8]) -> io::Result<usize> {
        self.0.borrow_mut().bytes.extend_from_slice(b);
        Ok(b.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl Seek for Sink {
    fn seek(&mut self, pos: SeekFrom) -> io::Result<u64> {
        let p = self.0.borrow();
        let here = p.offset + p.bytes.len() as u64;
        match pos {
            SeekFrom::Current(0) | SeekFrom::End(0) => Ok(here),
            SeekFrom::Start(at) if at == here => Ok(here),
            _ => Err(io::Error::new(io::ErrorKind::Unsupported, "the MCAP sink only appends")),
        }
    }
}

/// An MCAP record: opcode, length, content.
fn record(out: &mut Vec<u8>, opcode: u8, content: &[u8]) {
    out.push(opcode);
    out.extend_from_slice(&(content.len() as u64).to_le_bytes());
    out.extend_from_slice(content);
}

/// An MCAP string: u32 length, UTF-8 bytes.
fn string(out: &mut Vec<u8>, s: &str) {
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
}

/// What closes the file at a checkpoint: a Metadata record `name` (if any), a DataEnd (no
/// CRC), a Footer without a summary, the magic.
fn tail(metadata: Option<&mcap::records::Metadata>) -> Vec<u8> {
    let mut out = Vec::new();
    if let Some(md) = metadata {
        let mut map = Vec::new();
        for (k, v) in &md.metadata {
            string(&mut map, k);
            string(&mut map, v);
        }
        let mut content = Vec::new();
        string(&mut content, &md.name);
        content.extend_from_slice(&(map.len() as u32).to_le_bytes());
        content.extend_from_slice(&map);
        record(&mut out, 0x0C, &content);
    }
    record(&mut out, 0x0F, &0u32.to_le_bytes());
    record(&mut out, 0x02, &[0u8; 20]);
    out.extend_from_slice(MAGIC);
    out
}

/// The `bass` metadata record of `side` (its rows left out: they are the ChunkInfo messages).
fn facts(side: &Sidecar) -> io::Result<mcap::records::Metadata> {
    let mut facts = BTreeMap::new();
    let mut bare = side.clone();
    bare.chunks.clear();
    facts.insert(METADATA_SIDECAR.to_string(), serde_json::to_string(&bare)?);
    for (part, v) in [
        ("acquisition", serde_json::to_value(&side.acquisition)?),
        ("recording", serde_json::to_value(&side.recording)?),
    ] {
        for (k, v) in v.as_object().into_iter().flatten() {
            let s = v.as_str().map_or_else(|| v.to_string(), str::to_owned);
            facts.insert(format!("{part}.{k}"), s);
        }
    }
    Ok(mcap::records::Metadata { name: METADATA_NAME.into(), metadata: facts })
}

/// A recording being written as MCAP.
pub struct McapOut {
    /// None once finished.
    w: Option<mcap::Writer<Sink>>,
    sink: Sink,
    file: File,
    /// Frames of the file on the disk (those of the messages before the last checkpoint).
    frames_on_disk: u64,
    pub(super) path: PathBuf,
    dir: Option<PathBuf>,
    topics: Topics,
    ch: [u16; 3],
    counts: [u64; 3],
    channels: usize,
    rate: u64,
    nfpc: u64,
    epoch: u64,
    info: AudioInfo,
    /// The RawAudio channel, if asked for.
    raw: Option<foxglove::Channel>,
    /// Frames in the file so far (lost ones included).
    frames: u64,
    /// Acquisition frame of the first frame of `pending`.
    pending_from: u64,
    /// Interleaved samples of frames not yet in a message.
    pending: Vec<i32>,
    lost_before: u64,
    /// The file's first frame, once known.
    first: Option<u64>,
    seq: u32,
    last_row: Option<ChunkRow>,
    first_ns: Option<u64>,
    last_ns: u64,
    buf: Vec<u8>,
}

impl McapOut {
    /// Starts the MCAP file of `layout` on `file` (created by the caller).
    pub fn new(
        layout: &Layout,
        file: File,
        broker: &str,
        channels: usize,
        rate: u32,
        nfpc: u32,
        epoch: u64,
    ) -> io::Result<McapOut> {
        // Chunks are made in memory and written whole (no seeking back into the file).
        let opts = mcap::WriteOptions::new()
            .profile("ros2")
            .library(format!("bass {}; mcap-rs 0.24", env!("CARGO_PKG_VERSION")))
            .compression(None)
            .disable_seeking(true);
        let sink = Sink::default();
        let mut w = opts.create(sink.clone()).map_err(mcap_err)?;
        let topics = Topics::of(broker);
        let mut ch = [0u16; 3];
        for (i, (ty, def, topic, qos)) in [
            (ros2::AUDIO_INFO, ros2::AUDIO_INFO_DEFINITION, &topics.info, QOS_LATCHED),
            (ros2::CHUNK_INFO, ros2::CHUNK_INFO_DEFINITION, &topics.chunks, QOS_STREAM),
            (ros2::AUDIO_DATA_STAMPED, ros2::AUDIO_DATA_STAMPED_DEFINITION, &topics.audio, QOS_STREAM),
        ]
        .into_iter()
        .enumerate()
        {
            let schema = w.add_schema(ty, ros2::SCHEMA_ENCODING, def.as_bytes()).map_err(mcap_err)?;
            let meta = BTreeMap::from([("offered_qos_profiles".to_string(), qos.to_string())]);
            ch[i] = w.add_channel(schema, topic, ros2::MESSAGE_ENCODING, &meta).map_err(mcap_err)?;
        }
        let info = AudioInfo::s32le(u8::try_from(channels).unwrap_or(u8::MAX), rate);
        Ok(McapOut {
            w: Some(w),
            sink,
            file,
            frames_on_disk: 0,
            path: layout.file().to_owned(),
            dir: layout.dir().map(Path::to_owned),
            topics,
            ch,
            counts: [0; 3],
            channels,
            rate: u64::from(rate.max(1)),
            nfpc: u64::from(nfpc.max(1)),
            epoch,
            info,
            raw: None,
            frames: 0,
            pending_from: 0,
            pending: Vec::new(),
            lost_before: 0,
            first: None,
            seq: 0,
            last_row: None,
            first_ns: None,
            last_ns: 0,
            buf: Vec::new(),
        })
    }

    /// Adds the `foxglove_msgs/msg/RawAudio` channel of `broker` (before the first message).
    pub fn add_raw_audio(&mut self, broker: &str) -> io::Result<()> {
        let rate = u32::try_from(self.rate).unwrap_or(u32::MAX);
        let channels = self.channels;
        let raw =
            foxglove::Channel::add(self.writer()?, broker, rate, channels, QOS_STREAM).map_err(mcap_err)?;
        self.raw = Some(raw);
        Ok(())
    }

    /// Frames in the file so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The file's first frame is `first`.
    pub fn begin(&mut self, first: u64) {
        self.pending_from = first;
        self.first = Some(first);
    }

    /// Frames in the messages written so far (from the file's first frame to the end of the
    /// last message; frames lost after it are counted by the next message).
    pub fn frames_in_messages(&self) -> u64 {
        self.first.map_or(0, |f| self.pending_from - self.lost_before - f)
    }

    /// Frames of the file on the disk: those of the last checkpoint.
    pub fn frames_on_disk(&self) -> u64 {
        self.frames_on_disk
    }

    /// One frame's samples (the selected channels, in order).
    pub fn push(&mut self, s: i32) {
        self.pending.push(s);
        if self.pending.len() % self.channels == 0 {
            self.frames += 1;
        }
    }

    /// `n` frames lost after the pending ones: those become a message of their own first.
    pub fn lose(&mut self, n: u64, rows: &[ChunkRow]) -> io::Result<()> {
        self.emit(rows, true)?;
        self.pending_from += n;
        self.lost_before += n;
        self.frames += n;
        Ok(())
    }

    fn pending_frames(&self) -> u64 {
        (self.pending.len() / self.channels) as u64
    }

    /// Writes a message pair for every pending run that fills its chunk (or every run, `all`).
    pub fn emit(&mut self, rows: &[ChunkRow], all: bool) -> io::Result<()> {
        while self.pending_frames() > 0 {
            let p0 = self.pending_from;
            let chunk = (p0 - 1) / self.nfpc * self.nfpc + 1;
            let to_end = chunk + self.nfpc - p0;
            let n = self.pending_frames().min(to_end);
            if n < to_end && !all {
                break;
            }
            let i = rows.partition_point(|r| r.first_frame < chunk);
            let row = rows.get(i).filter(|r| r.first_frame == chunk).copied();
            self.write_run(p0, n, row)?;
            self.pending.drain(..n as usize * self.channels);
            self.pending_from += n;
        }
        Ok(())
    }

    fn write_run(&mut self, p0: u64, n: u64, row: Option<ChunkRow>) -> io::Result<()> {
        let basis = row.or(self.last_row);
        let stamp_ns = basis.map_or(0, |r| {
            let d = i128::from(p0) - i128::from(r.first_frame);
            (i128::from(r.realtime_ns) + d * 1_000_000_000 / i128::from(self.rate)).max(0) as u64
        });
        if row.is_some() {
            self.last_row = row;
        }
        let log_time = stamp_ns.max(self.last_ns);
        if self.first_ns.is_none() {
            self.first_ns = Some(log_time);
            self.info.encode(&mut self.buf);
            self.message(0, log_time)?;
        }
        self.last_ns = log_time;
        let header = Header { stamp: Time::from_ns(stamp_ns), frame_id: String::new() };
        let r = row.unwrap_or_default();
        ChunkInfo {
            header: header.clone(),
            epoch: self.epoch,
            first_frame: p0,
            frames: n as u32,
            chunk_first_frame: r.first_frame,
            chunk_frames: self.nfpc as u32,
            flags: r.flags,
            monotonic_ns: r.mono_ns,
            realtime_ns: r.realtime_ns,
            lost_before: std::mem::take(&mut self.lost_before),
            bound_ns: r.bound_or_unknown(),
            missing_channels: r.missing_channels,
            unaligned_channels: r.unaligned_channels,
        }
        .encode(&mut self.buf);
        self.message(1, log_time)?;
        let samples = n as usize * self.channels;
        AudioDataStamped::encode_samples(&header, &self.pending[..samples], &mut self.buf);
        self.message(2, log_time)?;
        if let Some(raw) = &mut self.raw {
            raw.encode(header.stamp, &self.pending[..samples], &mut self.buf);
            raw.messages += 1;
            let id = raw.id;
            self.send(id, log_time)?;
        }
        self.seq += 1;
        Ok(())
    }

    fn message(&mut self, k: usize, log_time: u64) -> io::Result<()> {
        self.counts[k] += 1;
        self.send(self.ch[k], log_time)
    }

    /// Writes `buf` as the message of the current sequence number on channel `channel_id`.
    fn send(&mut self, channel_id: u16, log_time: u64) -> io::Result<()> {
        let h =
            mcap::records::MessageHeader { channel_id, sequence: self.seq, log_time, publish_time: log_time };
        let w = self.w.as_mut().ok_or_else(|| io::Error::other("the MCAP file is finished"))?;
        w.write_to_known_channel(&h, &self.buf).map_err(mcap_err)
    }

    /// A checkpoint: closes the chunk being written and puts every record so far on the disk,
    /// with a tail holding `side` (the facts of [`McapOut::frames_in_messages`] frames), so
    /// that the file is complete as it is. On an error the file is as it was.
    pub fn checkpoint(&mut self, side: &Sidecar) -> io::Result<()> {
        let frames = self.frames_in_messages();
        self.writer()?.flush().map_err(mcap_err)?;
        self.commit(&tail(Some(&facts(side)?)))?;
        self.frames_on_disk = frames;
        Ok(())
    }

    /// Writes the records not yet on the disk and `tail` after them, in one write at the end
    /// of the records on the disk (over the last tail); `tail` is not one of them (the next
    /// commit writes over it). On an error nothing was added to the records on the disk, and
    /// the file is cut back to them (freeing what the failed write took).
    fn commit(&mut self, tail: &[u8]) -> io::Result<()> {
        let mut p = self.sink.0.borrow_mut();
        let n = p.bytes.len();
        p.bytes.extend_from_slice(tail);
        let r = self.file.write_all_at(&p.bytes, p.offset);
        p.bytes.truncate(n);
        if let Err(e) = r {
            let _ = self.file.set_len(p.offset);
            return Err(e);
        }
        p.offset += n as u64;
        p.bytes.clear();
        Ok(())
    }

    fn writer(&mut self) -> io::Result<&mut mcap::Writer<Sink>> {
        self.w.as_mut().ok_or_else(|| io::Error::other("the MCAP file is finished"))
    }

    /// Writes the rest, the `bass` metadata record, the summary, then `metadata.yaml` (a bag
    /// directory). Returns the MCAP file's size.
    pub fn finish(&mut self, rows: &[ChunkRow], side: &Sidecar) -> io::Result<u64> {
        self.emit(rows, true)?;
        let md = facts(side)?;
        let mut w = self.w.take().ok_or_else(|| io::Error::other("the MCAP file is finished"))?;
        w.write_metadata(&md).map_err(mcap_err)?;
        w.finish().map_err(mcap_err)?;
        drop(w);
        self.commit(&[])?;
        let size = self.sink.0.borrow().offset;
        // The last tail may have been longer than the summary written over it.
        self.file.set_len(size)?;
        self.file.sync_all()?;
        if let Some(dir) = &self.dir {
            self.write_metadata_yaml(dir)?;
        }
        Ok(size)
    }

    /// After a failed write (a full disk): cuts the file back to the last checkpoint and
    /// closes it there with `side` (the facts of [`McapOut::frames_on_disk`] frames and the
    /// recording's end), or without facts if even they do not fit. Returns the file's size.
    pub fn close_at_checkpoint(&mut self, side: &Sidecar) -> io::Result<u64> {
        // Nothing more from the writer (dropping it finishes into the sink, which is dropped).
        self.w = None;
        self.sink.0.borrow_mut().bytes.clear();
        let md = facts(side)?;
        if let Err(e) = self.commit(&tail(Some(&md))) {
            self.commit(&tail(None)).map_err(|_| e)?;
        }
        self.file.sync_all()?;
        let size = self.file.metadata()?.len();
        if let Some(dir) = &self.dir {
            // Best effort: the bag's MCAP file is complete without it.
            let _ = self.write_metadata_yaml(dir);
        }
        Ok(size)
    }

    fn write_metadata_yaml(&self, dir: &Path) -> io::Result<()> {
        let yaml = self.metadata_yaml();
        // Never through a planted link: whatever is at the temporary name is removed (a link
        // itself, not its target), the file made new (O_EXCL), then renamed over
        // metadata.yaml (a link there is replaced, not followed).
        let tmp = dir.join(".metadata.yaml.tmp");
        match std::fs::remove_file(&tmp) {
            Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
            _ => {}
        }
        let mut f = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        f.write_all(yaml.as_bytes())?;
        f.sync_all()?;
        std::fs::rename(&tmp, dir.join("metadata.yaml"))
    }

    /// rosbag2's `metadata.yaml` (version 5, which every rosbag2 release and rosbags read).
    fn metadata_yaml(&self) -> String {
        let start = self.first_ns.unwrap_or(0);
        let duration = self.last_ns.saturating_sub(start);
        let total = self.counts.iter().sum::<u64>() + self.raw.as_ref().map_or(0, |r| r.messages);
        let file = self.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let mut y = String::from("rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n");
        y += &format!("  duration:\n    nanoseconds: {duration}\n");
        y += &format!("  starting_time:\n    nanoseconds_since_epoch: {start}\n");
        y += &format!("  message_count: {total}\n  topics_with_message_count:\n");
        let raw = self.raw.as_ref().map(|r| (&r.topic, RAW_AUDIO, QOS_STREAM, r.messages));
        for (topic, ty, qos, count) in [
            (&self.topics.info, ros2::AUDIO_INFO, QOS_LATCHED, self.counts[0]),
            (&self.topics.chunks, ros2::CHUNK_INFO, QOS_STREAM, self.counts[1]),
            (&self.topics.audio, ros2::AUDIO_DATA_STAMPED, QOS_STREAM, self.counts[2]),
        ]
        .into_iter()
        .chain(raw)
        {
            y += &format!(
                "    - topic_metadata:\n        name: {topic}\n        type: {ty}\n        serialization_format: cdr\n        offered_qos_profiles: {}\n      message_count: {count}\n",
                yaml_quote(qos),
            );
        }
        y += "  compression_format: \"\"\n  compression_mode: \"\"\n";
        y += &format!("  relative_file_paths:\n    - {file}\n  files:\n    - path: {file}\n");
        y += &format!("      starting_time:\n        nanoseconds_since_epoch: {start}\n");
        y += &format!("      duration:\n        nanoseconds: {duration}\n      message_count: {total}\n");
        y
    }
}

/// A YAML double-quoted scalar.
fn yaml_quote(s: &str) -> String {
    let mut q = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => q += "\\\"",
            '\\' => q += "\\\\",
            '\n' => q += "\\n",
            c => q.push(c),
        }
    }
    q + "\""
}
