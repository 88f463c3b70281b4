//! `bass record --check REC.mcap` (or a bag directory): an MCAP recording of `bass record`,
//! read front to back, its messages held against each other and against its `bass` metadata
//! record (the facts a WAV's sidecar holds); RawAudio messages (`--foxglove-audio`) against the
//! audio messages they convert ([`super::foxglove::Check`]).

use std::collections::HashMap;
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use basskit::ros2::foxglove::RAW_AUDIO;
use basskit::ros2::{self, AudioDataStamped, ChunkInfo};
use basskit::sidecar::{ChunkRow, Lost, Sidecar};
use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::foxglove;
use super::mcap_out::{METADATA_NAME, METADATA_SIDECAR};

/// Largest record read (a message of 64 channels × 1 Mi frames of 32 bits).
const RECORD_LIMIT: usize = 256 << 20;

/// What the messages of the file say.
#[derive(Default)]
struct Contents {
    profile: String,
    /// The `bass` metadata record's facts (the last one).
    facts: Option<Sidecar>,
    /// ChunkInfo and the audio message's sample count, in file order.
    runs: Vec<(ChunkInfo, usize)>,
    /// The RawAudio messages, each against its audio message.
    raw: foxglove::Check,
    /// The footer points to a summary.
    summary: bool,
    problems: Vec<String>,
}

/// The MCAP file of `path`: itself, or the one `.mcap` file of a bag directory.
fn resolve(path: &Path) -> Result<PathBuf, String> {
    if !path.is_dir() {
        return Ok(path.to_owned());
    }
    let found: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    match found.as_slice() {
        [one] => Ok(one.clone()),
        [] => Err(format!("{} holds no .mcap file", path.display())),
        _ => Err(format!("{} holds {} .mcap files", path.display(), found.len())),
    }
}

/// Reads every record of `file`.
fn read(file: &mut File) -> Contents {
    let mut r = Contents::default();
    let opts = LinearReaderOptions::default().with_record_length_limit(RECORD_LIMIT);
    let mut reader = LinearReader::new_with_options(opts);
    let mut schemas: HashMap<u16, String> = HashMap::new();
    let mut kinds: HashMap<u16, &'static str> = HashMap::new();
    let mut pending: Option<(u32, ChunkInfo)> = None;
    while let Some(ev) = reader.next_event() {
        let ev = match ev {
            Ok(ev) => ev,
            Err(e) => {
                r.problems.push(format!(
                    "not a readable MCAP file: {e} (`mcap recover` keeps the complete messages of a damaged file)"
                ));
                return r;
            }
        };
        let (opcode, data) = match ev {
            LinearReadEvent::ReadRequest(need) => {
                match file.read(reader.insert(need)) {
                    Ok(n) => reader.notify_read(n),
                    Err(e) => {
                        r.problems.push(format!("read: {e}"));
                        return r;
                    }
                }
                continue;
            }
            LinearReadEvent::Record { opcode, data } => (opcode, data),
        };
        let rec = match mcap::parse_record(opcode, data) {
            Ok(rec) => rec,
            Err(e) => {
                r.problems.push(format!("a bad record: {e}"));
                return r;
            }
        };
        match rec {
            Record::Header(h) => r.profile = h.profile,
            Record::Schema { header, .. } => {
                schemas.insert(header.id, header.name);
            }
            Record::Channel(c) => {
                let kind = match schemas.get(&c.schema_id).map(String::as_str) {
                    Some(ros2::CHUNK_INFO) => ros2::CHUNK_INFO,
                    Some(ros2::AUDIO_DATA_STAMPED) => ros2::AUDIO_DATA_STAMPED,
                    Some(RAW_AUDIO) => RAW_AUDIO,
                    _ => continue,
                };
                kinds.insert(c.id, kind);
            }
            Record::Message { header, data } => match kinds.get(&header.channel_id) {
                Some(&ros2::CHUNK_INFO) => match ChunkInfo::decode(&data) {
                    Ok(m) => {
                        if let Some((s, _)) = pending.replace((header.sequence, m)) {
                            r.problems.push(format!("ChunkInfo message {s} has no audio message after it"));
                        }
                    }
                    Err(e) => r.problems.push(format!("ChunkInfo message {}: {e}", header.sequence)),
                },
                Some(&RAW_AUDIO) => r.raw.raw(header.sequence, &data),
                Some(_) => match (AudioDataStamped::decode(&data), pending.take()) {
                    (Ok(a), Some((s, info))) if s == header.sequence => {
                        r.runs.push((info, a.data.len() / 4));
                        r.raw.audio(s, a);
                    }
                    (Err(e), _) => r.problems.push(format!("audio message {}: {e}", header.sequence)),
                    _ => r.problems.push(format!(
                        "audio message {} has no ChunkInfo with its sequence number before it",
                        header.sequence
                    )),
                },
                None => {}
            },
            Record::Metadata(m) if m.name == METADATA_NAME => {
                match m.metadata.get(METADATA_SIDECAR).map(|j| serde_json::from_str::<Sidecar>(j)) {
                    Some(Ok(s)) => r.facts = Some(s),
                    Some(Err(e)) => r.problems.push(format!("the {METADATA_NAME:?} metadata record: {e}")),
                    None => r
                        .problems
                        .push(format!("the {METADATA_NAME:?} metadata record has no {METADATA_SIDECAR:?}")),
                }
            }
            Record::Footer(f) => r.summary = f.summary_start != 0,
            _ => {}
        }
    }
    if let Some((s, _)) = pending {
        r.problems.push(format!("ChunkInfo message {s} has no audio message after it"));
    }
    r
}

/// The messages against the facts: they tile the file from its first frame, hold the frames
/// they say, and their losses and chunk rows (GAP frames) are the facts'. The rows are the
/// ChunkInfo messages' (the facts in the file hold none), put into `side`.
fn against_facts(side: &mut Sidecar, runs: &[(ChunkInfo, usize)]) -> Vec<String> {
    let mut v = Vec::new();
    let mut rows: Vec<ChunkRow> = Vec::new();
    let (a, r) = (&side.acquisition, &side.recording);
    let (mut next, mut losses) = (r.first_frame, Vec::<Lost>::new());
    for (m, samples) in runs {
        if m.epoch != a.epoch {
            v.push(format!(
                "message at frame {}: epoch {}; the recording's is {}",
                m.first_frame, m.epoch, a.epoch
            ));
        }
        if m.first_frame != next.saturating_add(m.lost_before) {
            v.push(format!(
                "message at frame {}: after frame {} and {} lost it must be at {}",
                m.first_frame,
                next.saturating_sub(1),
                m.lost_before,
                next.saturating_add(m.lost_before)
            ));
        }
        if m.lost_before > 0 {
            losses.push(Lost { first_frame: next, frames: m.lost_before });
        }
        if *samples as u64 != u64::from(m.frames) * r.channels.len() as u64 {
            v.push(format!(
                "message at frame {}: {samples} samples for {} frames of {} channels",
                m.first_frame,
                m.frames,
                r.channels.len()
            ));
        }
        match (m.row(), rows.last()) {
            (Some(row), Some(p)) if p.first_frame == row.first_frame && *p != row => v.push(format!(
                "message at frame {}: chunk {} described as {row:?}; a message before it said {p:?}",
                m.first_frame, row.first_frame
            )),
            (Some(row), p) if p.map_or(true, |p| p.first_frame < row.first_frame) => rows.push(row),
            _ => {}
        }
        next = m.first_frame.saturating_add(u64::from(m.frames));
    }
    let frames = next - r.first_frame;
    if frames != r.frames {
        v.push(format!("the messages hold {frames} frames (lost ones included); the facts say {}", r.frames));
    }
    if losses != side.losses {
        v.push(format!("the messages' losses are {losses:?}; the facts say {:?}", side.losses));
    }
    if (r.seconds - r.frames as f64 / f64::from(a.sample_rate.max(1))).abs() > 1e-6 {
        v.push(format!("recording.seconds {} is not frames / rate", r.seconds));
    }
    side.chunks = rows;
    v.extend(side.problems());
    v
}

/// `bass record --check` of an MCAP recording `path` (a `.mcap` file or a bag directory): the
/// one-line summary if its messages and facts agree, else every problem found.
pub fn check_mcap(path: &Path) -> Result<String, Vec<String>> {
    let file_path = resolve(path).map_err(|e| vec![e])?;
    let mut f = File::open(&file_path).map_err(|e| vec![format!("{}: {e}", file_path.display())])?;
    let got = read(&mut f);
    let mut v = got.problems;
    if got.profile != "ros2" && v.is_empty() {
        v.push(format!("MCAP profile {:?}, not ros2", got.profile));
    }
    let Some(mut side) = got.facts else {
        v.push(format!(
            "no {METADATA_NAME:?} metadata record: not a bass recording, or one whose recorder was killed before its first checkpoint"
        ));
        return Err(v);
    };
    v.extend(against_facts(&mut side, &got.runs));
    let raw_messages = got.raw.messages;
    v.extend(got.raw.finish(got.runs.len(), side.acquisition.sample_rate, side.recording.channels.len()));
    if !v.is_empty() {
        return Err(v);
    }
    let (a, r) = (&side.acquisition, &side.recording);
    let mut line = format!(
        "ok: {}: {} frames ({:.3} s), frames {}..={} of epoch {}, {} channels, 32 bits, MCAP ({} audio messages); {} frames lost in {} losses, {} gap frames, {} chunk rows{}",
        file_path.display(),
        r.frames,
        r.seconds,
        r.first_frame,
        side.last_frame(),
        a.epoch,
        r.channels.len(),
        got.runs.len(),
        r.lost_frames,
        side.losses.len(),
        r.gap_frames,
        side.chunks.len(),
        side.ext_summary(),
    );
    if raw_messages > 0 {
        line += &format!("; {raw_messages} RawAudio messages (pcm-s16) agree with them");
    }
    if let Some(q) = r.requested_first_frame {
        line += &format!("; started {} frames after the requested frame {q}", r.started_after_requested);
    }
    if r.in_progress {
        line += "; in progress: the last checkpoint of a recorder that did not finish (killed?)";
    } else if !got.summary {
        line += &format!("; without a summary (ended: {})", r.end);
    }
    Ok(line)
}
