//! `bass record --format mcap DIR`: the recording as a rosbag2 bag directory, `DIR/` holding
//! `DIR/<name>_0.mcap` and `DIR/metadata.yaml` (`<name>` the directory's own name).
//!
//! The MCAP file (profile `ros2`, chunked, uncompressed, as rosbag2's MCAP plugin writes by
//! default) holds three channels, each with a `ros2msg` schema and CDR messages from
//! [`bassclient::ros2`]:
//!
//! - `/bass/<broker>/audio_info`: one `audio_common_msgs/msg/AudioInfo`;
//! - `/bass/<broker>/chunk_info`: per run of frames (a port chunk, or its part in the file), a
//!   `bass_msgs/msg/ChunkInfo` with the frame index, frames, flags, both clocks and the loss
//!   before it;
//! - `/bass/<broker>/audio`: the same run's `AudioDataStamped`, interleaved S32LE, written just
//!   after its ChunkInfo with the same MCAP sequence number and log time.
//!
//! Frames the recorder lost are in no message (never zeros presented as audio): the next
//! ChunkInfo's `lost_before` counts them. A metadata record `bass` holds the sidecar's file-level
//! facts (acquisition, recording, losses: `bassclient::sidecar` without the rows, which are the
//! ChunkInfo messages). `metadata.yaml` is there for rosbag2 releases that open only a bag
//! directory (`ros2 bag play DIR`); the MCAP file alone is complete for every other reader.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, BufWriter};
use std::path::{Path, PathBuf};

use bassclient::ros2::{self, AudioDataStamped, AudioInfo, ChunkInfo, Header, Time, Topics};
use bassclient::sidecar::{ChunkRow, Sidecar};

/// Name of the metadata record holding the sidecar's facts.
pub const METADATA_NAME: &str = "bass";
/// Its key holding them as JSON (a `bassclient::sidecar::Sidecar` without chunk rows).
pub const METADATA_SIDECAR: &str = "sidecar";

/// QoS offered (rosbag2's `offered_qos_profiles`, the integer form every rosbag2 release reads):
/// reliable, volatile, keep last 100, for the audio and chunk topics.
const QOS_STREAM: &str = "- history: 1\n  depth: 100\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 9223372036\n    nsec: 854775807\n  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n  avoid_ros_namespace_conventions: false\n";
/// For AudioInfo: transient local, so a subscriber that joins late still gets it.
const QOS_LATCHED: &str = "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n  deadline:\n    sec: 9223372036\n    nsec: 854775807\n  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n  avoid_ros_namespace_conventions: false\n";

fn mcap_err(e: mcap::McapError) -> io::Error {
    io::Error::other(e.to_string())
}

/// The MCAP file of a bag directory `dir`.
pub fn file_in(dir: &Path) -> PathBuf {
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "bass".into());
    dir.join(format!("{name}_0.mcap"))
}

/// A recording being written as MCAP.
pub struct McapOut {
    /// None once finished.
    w: Option<mcap::Writer<BufWriter<File>>>,
    pub(super) path: PathBuf,
    dir: PathBuf,
    topics: Topics,
    ch: [u16; 3],
    counts: [u64; 3],
    channels: usize,
    rate: u64,
    nfpc: u64,
    epoch: u64,
    info: AudioInfo,
    /// Frames in the file so far (lost ones included).
    frames: u64,
    /// Acquisition frame of the first frame of `pending`.
    pending_from: u64,
    /// Interleaved samples of frames not yet in a message.
    pending: Vec<i32>,
    lost_before: u64,
    seq: u32,
    last_row: Option<ChunkRow>,
    first_ns: Option<u64>,
    last_ns: u64,
    buf: Vec<u8>,
}

impl McapOut {
    /// Starts `dir/<name>_0.mcap` on `file` (created by the caller).
    pub fn new(
        dir: &Path,
        file: File,
        broker: &str,
        channels: usize,
        rate: u32,
        nfpc: u32,
        epoch: u64,
    ) -> io::Result<McapOut> {
        let opts = mcap::WriteOptions::new()
            .profile("ros2")
            .library(format!("bass {}; mcap-rs 0.24", env!("CARGO_PKG_VERSION")))
            .compression(None);
        let mut w = opts.create(BufWriter::new(file)).map_err(mcap_err)?;
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
            path: file_in(dir),
            dir: dir.to_owned(),
            topics,
            ch,
            counts: [0; 3],
            channels,
            rate: u64::from(rate.max(1)),
            nfpc: u64::from(nfpc.max(1)),
            epoch,
            info,
            frames: 0,
            pending_from: 0,
            pending: Vec::new(),
            lost_before: 0,
            seq: 0,
            last_row: None,
            first_ns: None,
            last_ns: 0,
            buf: Vec::new(),
        })
    }

    /// Frames in the file so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The file's first frame is `first`.
    pub fn begin(&mut self, first: u64) {
        self.pending_from = first;
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
        let r = row.unwrap_or(ChunkRow { first_frame: 0, frames: 0, mono_ns: 0, realtime_ns: 0, flags: 0 });
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
        }
        .encode(&mut self.buf);
        self.message(1, log_time)?;
        AudioDataStamped::encode_samples(&header, &self.pending[..n as usize * self.channels], &mut self.buf);
        self.message(2, log_time)?;
        self.seq += 1;
        Ok(())
    }

    fn message(&mut self, k: usize, log_time: u64) -> io::Result<()> {
        let h = mcap::records::MessageHeader {
            channel_id: self.ch[k],
            sequence: self.seq,
            log_time,
            publish_time: log_time,
        };
        self.counts[k] += 1;
        let w = self.w.as_mut().ok_or_else(|| io::Error::other("the MCAP file is finished"))?;
        w.write_to_known_channel(&h, &self.buf).map_err(mcap_err)
    }

    /// Writes what is complete to the disk (a checkpoint: a killed recorder leaves a file
    /// without its summary, which `mcap recover` completes).
    pub fn flush(&mut self) -> io::Result<()> {
        self.writer()?.flush().map_err(mcap_err)
    }

    fn writer(&mut self) -> io::Result<&mut mcap::Writer<BufWriter<File>>> {
        self.w.as_mut().ok_or_else(|| io::Error::other("the MCAP file is finished"))
    }

    /// Writes the rest, the `bass` metadata record, the summary, then `metadata.yaml`.
    /// Returns the MCAP file's size.
    pub fn finish(&mut self, rows: &[ChunkRow], side: &Sidecar) -> io::Result<u64> {
        self.emit(rows, true)?;
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
        let md = mcap::records::Metadata { name: METADATA_NAME.into(), metadata: facts };
        let mut w = self.w.take().ok_or_else(|| io::Error::other("the MCAP file is finished"))?;
        w.write_metadata(&md).map_err(mcap_err)?;
        w.finish().map_err(mcap_err)?;
        w.into_inner().into_inner().map_err(|e| e.into_error())?.sync_all()?;
        let size = std::fs::metadata(&self.path)?.len();
        let yaml = self.metadata_yaml(size);
        // Never through a planted link: whatever is at the temporary name is removed (a link
        // itself, not its target), the file made new (O_EXCL), then renamed over
        // metadata.yaml (a link there is replaced, not followed).
        let tmp = self.dir.join(".metadata.yaml.tmp");
        match std::fs::remove_file(&tmp) {
            Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
            _ => {}
        }
        let mut f = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        io::Write::write_all(&mut f, yaml.as_bytes())?;
        f.sync_all()?;
        std::fs::rename(&tmp, self.dir.join("metadata.yaml"))?;
        Ok(size)
    }

    /// rosbag2's `metadata.yaml` (version 5, which every rosbag2 release and rosbags read).
    fn metadata_yaml(&self, _size: u64) -> String {
        let start = self.first_ns.unwrap_or(0);
        let duration = self.last_ns.saturating_sub(start);
        let total: u64 = self.counts.iter().sum();
        let file = self.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let mut y = String::from("rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n");
        y += &format!("  duration:\n    nanoseconds: {duration}\n");
        y += &format!("  starting_time:\n    nanoseconds_since_epoch: {start}\n");
        y += &format!("  message_count: {total}\n  topics_with_message_count:\n");
        for (k, (topic, ty, qos)) in [
            (&self.topics.info, ros2::AUDIO_INFO, QOS_LATCHED),
            (&self.topics.chunks, ros2::CHUNK_INFO, QOS_STREAM),
            (&self.topics.audio, ros2::AUDIO_DATA_STAMPED, QOS_STREAM),
        ]
        .into_iter()
        .enumerate()
        {
            y += &format!(
                "    - topic_metadata:\n        name: {topic}\n        type: {ty}\n        serialization_format: cdr\n        offered_qos_profiles: {}\n      message_count: {}\n",
                yaml_quote(qos),
                self.counts[k]
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
