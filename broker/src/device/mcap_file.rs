//! MCAP recordings of `bass record --format mcap` as a source of the file replay
//! (`device::file`): the recording's facts become the [`Sidecar`] a WAV recording has, and its
//! audio messages the frames a WAV holds, so the replay itself is the same for both.
//!
//! `sim:file:PATH.mcap` or `sim:file:DIR` (a bag directory holding one `.mcap` file). The file
//! is read twice, both times front to back: at the Acquire, every record is checked (each
//! `bass_msgs/msg/ChunkInfo` against the recording's chunk size, epoch and the messages before
//! it, each `AudioDataStamped` against its ChunkInfo's frames and the channel count, the `bass`
//! metadata record's losses against the messages' `lost_before`) and the sidecar is built; while
//! replaying, the audio messages are read again in order as the frames are due. Frame `i` of
//! the "file" is frame `first_frame + i` of the recording; a frame the recorder lost is in no
//! message and reads as zero (the replay publishes it as a loss, never as audio).

use std::collections::HashMap;
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use basskit::ros2::{self, AudioDataStamped, ChunkInfo};
use basskit::sidecar::{ChunkRow, Lost, Sidecar};
use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

/// Largest record read (a message of 64 channels × 1 Mi frames of 32 bits).
const RECORD_LIMIT: usize = 256 << 20;
/// The metadata record `bass record` writes, and its key holding the sidecar's facts.
const METADATA_NAME: &str = "bass";
const METADATA_SIDECAR: &str = "sidecar";

/// Whether `path` names an MCAP recording: a `.mcap` file or a directory holding one.
pub fn is_mcap(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "mcap") || path.is_dir()
}

/// The MCAP file of `path`: itself, or the one `.mcap` file of a bag directory.
pub fn resolve(path: &Path) -> Result<PathBuf, String> {
    if !path.is_dir() {
        return Ok(path.to_owned());
    }
    let mut found: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => Err(format!("{} holds no .mcap file", path.display())),
        n => Err(format!("{} holds {n} .mcap files; give the one to replay", path.display())),
    }
}

/// One audio message as the first pass found it.
#[derive(Clone, Copy, Debug)]
struct Run {
    first_frame: u64,
    frames: u64,
}

/// The audio of an MCAP recording, read front to back.
pub struct McapFrames {
    path: PathBuf,
    channels: usize,
    audio_channel: u16,
    runs: Vec<Run>,
    reader: Option<(File, LinearReader)>,
    /// Index in `runs` of the next audio message to read.
    next_run: usize,
    /// The last message read: its first frame and samples.
    current: Option<(u64, Vec<i32>)>,
    /// Recording frame of file frame 0.
    first_frame: u64,
}

/// Records no longer than [`RECORD_LIMIT`]; chunks checked against their CRC (where the
/// writer stored one) before any of their messages is used.
fn options() -> LinearReaderOptions {
    LinearReaderOptions::default().with_record_length_limit(RECORD_LIMIT).with_prevalidate_chunk_crcs(true)
}

/// Calls `f` on every record of `file`, in file order, until it returns `Ok(false)`.
fn each_record(
    file: &mut File,
    reader: &mut LinearReader,
    mut f: impl FnMut(Record<'_>) -> Result<bool, String>,
) -> Result<(), String> {
    while let Some(ev) = reader.next_event() {
        match ev.map_err(|e| format!("not a readable MCAP file: {e}"))? {
            LinearReadEvent::ReadRequest(need) => {
                let n = file.read(reader.insert(need)).map_err(|e| e.to_string())?;
                reader.notify_read(n);
            }
            LinearReadEvent::Record { opcode, data } => {
                let rec = mcap::parse_record(opcode, data).map_err(|e| format!("a bad record: {e}"))?;
                if !f(rec)? {
                    return Ok(());
                }
            }
        }
    }
    Ok(())
}

/// Reads and checks the MCAP recording `file` (opened by the caller, `path` for messages):
/// its audio, the sidecar it amounts to, and its channel count.
pub fn open(path: &Path, mut file: File) -> Result<(McapFrames, Sidecar), String> {
    let mut pass = FirstPass::default();
    let mut reader = LinearReader::new_with_options(options());
    each_record(&mut file, &mut reader, |rec| pass.record(rec))
        .map_err(|e| format!("{}: {e}", path.display()))?;
    pass.finish(path)
}

/// What the first pass over a recording's records collects: its schemas and channels, the
/// ChunkInfo and audio messages paired by sequence number, and the recording's facts.
#[derive(Default)]
struct FirstPass {
    schemas: HashMap<u16, String>,
    kinds: HashMap<u16, &'static str>,
    facts: Option<Sidecar>,
    infos: Vec<(u32, ChunkInfo)>,
    /// Sequence, bytes of data, index in `infos`.
    audio: Vec<(u32, usize, usize)>,
    /// A ChunkInfo waiting for its audio message.
    pending: Option<(u32, ChunkInfo)>,
    audio_channel: Option<u16>,
}

impl FirstPass {
    /// Takes one record; Ok(true) to go on.
    fn record(&mut self, rec: Record<'_>) -> Result<bool, String> {
        match rec {
            Record::Schema { header, .. } => {
                self.schemas.insert(header.id, header.name);
            }
            Record::Channel(c) => {
                let ty = self.schemas.get(&c.schema_id).map(String::as_str).unwrap_or("");
                let kind = match ty {
                    ros2::AUDIO_DATA_STAMPED => ros2::AUDIO_DATA_STAMPED,
                    ros2::CHUNK_INFO => ros2::CHUNK_INFO,
                    _ => return Ok(true),
                };
                if c.message_encoding != ros2::MESSAGE_ENCODING {
                    return Err(format!(
                        "channel {}: message encoding {:?}, not cdr",
                        c.topic, c.message_encoding
                    ));
                }
                if self.kinds.values().any(|&k| k == kind) && !self.kinds.contains_key(&c.id) {
                    return Err(format!(
                        "two {kind} channels (the second {}): which one to replay?",
                        c.topic
                    ));
                }
                if kind == ros2::AUDIO_DATA_STAMPED {
                    self.audio_channel = Some(c.id);
                }
                self.kinds.insert(c.id, kind);
            }
            Record::Message { header, data } => match self.kinds.get(&header.channel_id) {
                Some(&ros2::CHUNK_INFO) => {
                    let m = ChunkInfo::decode(&data)
                        .map_err(|e| format!("ChunkInfo message {}: {e}", header.sequence))?;
                    if let Some((s, _)) = self.pending.replace((header.sequence, m)) {
                        return Err(format!("ChunkInfo message {s} has no audio message after it"));
                    }
                }
                Some(_) => {
                    let m = AudioDataStamped::decode(&data)
                        .map_err(|e| format!("audio message {}: {e}", header.sequence))?;
                    match self.pending.take() {
                        Some((s, info)) if s == header.sequence => {
                            self.audio.push((s, m.data.len(), self.infos.len()));
                            self.infos.push((s, info));
                        }
                        _ => {
                            return Err(format!(
                                "audio message {} has no ChunkInfo with its sequence number before it",
                                header.sequence
                            ))
                        }
                    }
                }
                None => {}
            },
            Record::Metadata(m) if m.name == METADATA_NAME => {
                let json = m.metadata.get(METADATA_SIDECAR).ok_or_else(|| {
                    format!("its {METADATA_NAME:?} metadata record has no {METADATA_SIDECAR:?} entry")
                })?;
                let s: Sidecar = serde_json::from_str(json)
                    .map_err(|e| format!("its {METADATA_NAME:?} metadata record: {e}"))?;
                self.facts = Some(s);
            }
            _ => {}
        }
        Ok(true)
    }

    /// The frames to replay and the sidecar, once every record was read: refused when the
    /// facts are missing or the messages do not agree with them.
    fn finish(self, path: &Path) -> Result<(McapFrames, Sidecar), String> {
        let named = |e: String| format!("{}: {e}", path.display());
        let mut side = self.facts.ok_or_else(|| {
            named(format!(
                "no {METADATA_NAME:?} metadata record: not a bass recording, or its recorder was killed before the end \
                 (`mcap recover` keeps the messages, not the facts the replay needs)"
            ))
        })?;
        if let Some((s, _)) = self.pending {
            return Err(named(format!("ChunkInfo message {s} has no audio message after it")));
        }
        let audio_channel =
            self.audio_channel.ok_or_else(|| named(format!("no {} channel", ros2::AUDIO_DATA_STAMPED)))?;
        let (runs, rows, losses) = check_messages(&side, &self.infos, &self.audio).map_err(named)?;
        // The rows are the messages'; the losses must be the ones the facts say.
        if losses != side.losses {
            return Err(named(format!(
                "the messages' lost_before make the losses {losses:?}; its metadata says {:?}",
                side.losses
            )));
        }
        side.chunks = rows;
        if let Some(p) = side.problems().first() {
            return Err(named(format!("its recording does not agree with itself: {p}")));
        }
        let first_frame = side.recording.first_frame;
        let frames = McapFrames {
            path: path.to_owned(),
            channels: side.recording.channels.len(),
            audio_channel,
            runs,
            reader: None,
            next_run: 0,
            current: None,
            first_frame,
        };
        Ok((frames, side))
    }
}

/// The audio runs, chunk rows and losses the messages describe.
type Described = (Vec<Run>, Vec<ChunkRow>, Vec<Lost>);

/// Holds every ChunkInfo against the recording's facts and the one before it; returns the
/// audio runs, the chunk rows and the losses the messages describe.
fn check_messages(
    side: &Sidecar,
    infos: &[(u32, ChunkInfo)],
    audio: &[(u32, usize, usize)],
) -> Result<Described, String> {
    let (a, r) = (&side.acquisition, &side.recording);
    let nfpc = u64::from(a.frames_per_chunk.max(1));
    let channels = r.channels.len();
    let (mut runs, mut rows, mut losses) = (Vec::new(), Vec::<ChunkRow>::new(), Vec::<Lost>::new());
    let mut next = r.first_frame; // the frame after the last one accounted for
    for &(seq, bytes, k) in audio {
        let m = &infos[k].1;
        let at = |what: String| format!("ChunkInfo message {seq} (frame {}): {what}", m.first_frame);
        if m.frames == 0 {
            return Err(at("frames 0".into()));
        }
        if u64::from(m.chunk_frames) != nfpc {
            return Err(at(format!("chunk_frames {}; the recording's chunks hold {nfpc}", m.chunk_frames)));
        }
        if m.epoch != a.epoch {
            return Err(at(format!("epoch {}; the recording's is {}", m.epoch, a.epoch)));
        }
        let want = next.checked_add(m.lost_before).ok_or_else(|| at("lost_before overflows".into()))?;
        if m.first_frame != want {
            return Err(at(format!(
                "first_frame {}; after the message before it and lost_before {} it must be {want}",
                m.first_frame, m.lost_before
            )));
        }
        let last = m.first_frame + u64::from(m.frames) - 1;
        let chunk = (m.first_frame - 1) / nfpc * nfpc + 1;
        if last >= chunk + nfpc {
            return Err(at(format!(
                "{} frames pass the end of its chunk at frame {}",
                m.frames,
                chunk + nfpc - 1
            )));
        }
        if m.chunk_first_frame != 0 && m.chunk_first_frame != chunk {
            return Err(at(format!(
                "chunk_first_frame {}; its frames are in the chunk at {chunk}",
                m.chunk_first_frame
            )));
        }
        let need = u64::from(m.frames) * channels as u64 * 4;
        if bytes as u64 != need {
            return Err(format!(
                "audio message {seq}: {bytes} bytes of data; {} frames of {channels} S32LE channels are {need}",
                m.frames
            ));
        }
        if m.lost_before > 0 {
            match losses.last_mut() {
                Some(l) if l.first_frame + l.frames == next => l.frames += m.lost_before,
                _ => losses.push(Lost { first_frame: next, frames: m.lost_before }),
            }
        }
        if let Some(row) = m.row().filter(|_| rows.last().map_or(true, |p| p.first_frame < chunk)) {
            rows.push(row); // with its bound and masks (unknown and 0 in an older recording)
        }
        runs.push(Run { first_frame: m.first_frame, frames: u64::from(m.frames) });
        next = last + 1;
    }
    // Frames after the last message: lost at the end of the file.
    let end = r.first_frame.saturating_add(r.frames);
    if next > end {
        return Err(format!(
            "the messages reach frame {}; the recording ends at frame {}",
            next - 1,
            end - 1
        ));
    }
    if next < end {
        match losses.last_mut() {
            Some(l) if l.first_frame + l.frames == next => l.frames += end - next,
            _ => losses.push(Lost { first_frame: next, frames: end - next }),
        }
    }
    Ok((runs, rows, losses))
}

impl McapFrames {
    /// Starts reading the audio messages again from the start of the file.
    fn rewind(&mut self) -> Result<(), String> {
        let f = super::regular::open(&self.path, "MCAP")?;
        self.reader = Some((f, LinearReader::new_with_options(options())));
        self.next_run = 0;
        self.current = None;
        Ok(())
    }

    /// Reads the next audio message into `current`; false at the end of the file.
    fn advance(&mut self) -> Result<bool, String> {
        let Some(run) = self.runs.get(self.next_run).copied() else { return Ok(false) };
        let (ch, channels, seq) = (self.audio_channel, self.channels, self.next_run);
        let (file, reader) = self.reader.as_mut().expect("rewound before reading");
        let mut got = None;
        each_record(file, reader, |rec| match rec {
            Record::Message { header, data } if header.channel_id == ch => {
                let m = AudioDataStamped::decode(&data).map_err(|e| format!("audio message {seq}: {e}"))?;
                let s = m.samples().map_err(|e| format!("audio message {seq}: {e}"))?;
                if s.len() as u64 != run.frames * channels as u64 {
                    return Err(format!(
                        "audio message {seq} holds {} samples; it held {} when the replay started",
                        s.len(),
                        run.frames * channels as u64
                    ));
                }
                got = Some(s);
                Ok(false)
            }
            _ => Ok(true),
        })?;
        let s = got.ok_or_else(|| format!("the file ended before audio message {seq}"))?;
        self.current = Some((run.first_frame, s));
        self.next_run += 1;
        Ok(true)
    }

    /// Writes `n` frames from file frame `i` into `out` (interleaved), zeros where the
    /// recorder lost them. Reading backwards starts the file again (a loop).
    pub fn fill(&mut self, i: u64, out: &mut [i32], n: usize) -> Result<(), String> {
        let ch = self.channels;
        let a0 = self.first_frame + i;
        let behind = match &self.current {
            Some((f, _)) => a0 < *f,
            None => self.next_run > 0,
        };
        if self.reader.is_none() || behind {
            self.rewind()?;
        }
        for k in 0..n {
            let a = a0 + k as u64;
            loop {
                match &self.current {
                    Some((f, s)) if a < f + (s.len() / ch) as u64 => break,
                    _ => {
                        let upcoming = self.runs.get(self.next_run).map(|r| r.first_frame);
                        if upcoming.map_or(true, |f| a < f) {
                            break; // a lost frame (or past the end)
                        }
                        self.advance()?;
                    }
                }
            }
            let dst = &mut out[k * ch..(k + 1) * ch];
            match &self.current {
                Some((f, s)) if a >= *f && a < f + (s.len() / ch) as u64 => {
                    let at = (a - f) as usize * ch;
                    dst.copy_from_slice(&s[at..at + ch]);
                }
                _ => dst.fill(0),
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
