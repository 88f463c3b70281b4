//! The mirror's message handling, without Zenoh: chunk messages, source states and the
//! passing of time go in, a replica port and the counters come out. Time is an argument
//! (CLOCK_MONOTONIC ns), so the property test drives it with arbitrary message sequences.
//!
//! Rules (docs/network.md, "Guarantees" and "Defence"):
//! - every chunk is checked against the mirror's bounds ([`Bounds`]) before anything is
//!   allocated; outside them: refused, counted in `invalid_messages`;
//! - one serve instance is followed; chunks of another instance are refused while the
//!   followed one is still heard (two sources with one name: an error naming both); a switch
//!   happens only after the followed instance went silent (a serve restart);
//! - a new replica port (first chunk, new source epoch or geometry) at most once a second
//!   and [`RECREATIONS_PER_MINUTE`] times a minute; excess chunks are refused
//!   (`refused_epochs`);
//! - a chunk at the expected frame is published; ahead of it, the frames between are GAP
//!   frames counted lost upstream; behind it (late, duplicate) dropped and counted; further
//!   ahead than the time since the last chunk allows, refused (`refused_far_frames`): one
//!   forged chunk at frame 2^62 cannot freeze the replica;
//! - a source's `stopped`/`error`/`gone` state applies only if no chunk of the followed
//!   stream arrives after it (a forged state while data flows is ignored, `refused_states`);
//! - a replica that cannot be made (bounds, free space, a name held by another process)
//!   puts the mirror in an error state (`error` in the status) and is tried again on a later
//!   message, at most every [`RETRY_NS`]; never an exit;
//! - every text from the network is escaped ([`crate::text::escape`]) before it reaches the
//!   log, the status or the replica port.

use std::collections::VecDeque;
use std::path::PathBuf;

use bassclient::format::{chunk_flags, error_code};
use bassclient::{ChunkMeta, Geometry, PortParams, Source, State, Writer};
use serde::Serialize;

use super::bounds::Bounds;
use crate::net::SourceState;
use crate::text::escape;
use crate::wire;

const SEC: u64 = 1_000_000_000;
/// The followed instance counts as heard this long after its last chunk.
pub const INSTANCE_SILENCE_NS: u64 = 1_500_000_000;
/// The followed instance's liveliness token went away: it counts as silent this long after
/// its last chunk (not less: a token is easier to forge away than a stream of chunks).
pub const GONE_SILENCE_NS: u64 = 200_000_000;
/// Two instances count as heard together this long after the other's last chunk.
pub const TWO_SOURCES_HOLD_NS: u64 = 5 * SEC;
/// Shortest interval between two replica re-creations.
pub const RECREATION_INTERVAL_NS: u64 = SEC;
/// Most replica re-creations in a minute.
pub const RECREATIONS_PER_MINUTE: usize = 5;
/// A replica that could not be made is tried again after this long.
pub const RETRY_NS: u64 = 2 * SEC;
/// A source state is applied if no chunk of the followed stream came this long after it.
pub const STATE_CONFIRM_NS: u64 = 300_000_000;
/// Margin of time (beyond the window) a chunk may be ahead of what the elapsed time allows.
pub const AHEAD_MARGIN_NS: u64 = 2 * SEC;
/// Shortest interval between two log lines of one kind (the others are counted).
pub const LOG_EVERY_NS: u64 = 5 * SEC;

/// The mirror's counters (status file and log). Every text is escaped.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MirrorStatus {
    /// Replica port name.
    pub replica: String,
    /// Source broker name.
    pub source: String,
    /// The bridge runs without authentication (`--insecure`).
    pub insecure: bool,
    /// Replica epoch (0 = none yet).
    pub replica_epoch: u64,
    /// Source epoch followed.
    pub source_epoch: u64,
    /// Serve instance followed (hex), empty before the first chunk.
    pub source_instance: String,
    /// Newest replica frame.
    pub last_frame_index: u64,
    /// Chunks written with data.
    pub chunks_written: u64,
    /// Frames published as GAP for chunks that never arrived.
    pub gap_frames_lost: u64,
    /// Of those, frames the source side reported as not sent (its queue or its reader).
    pub gap_frames_source: u64,
    /// Chunks dropped for arriving late or twice.
    pub late_or_duplicate: u64,
    /// Messages refused by the decoder or outside this mirror's bounds.
    pub invalid_messages: u64,
    /// Chunks refused for a frame index further ahead than the elapsed time allows.
    pub refused_far_frames: u64,
    /// Chunks refused because they asked for a new replica sooner than the rate limit allows.
    pub refused_epochs: u64,
    /// Chunks refused because they came from a second serve instance while the followed one
    /// was heard.
    pub refused_other_source: u64,
    /// Source states ignored because the followed stream's chunks went on after them.
    pub refused_states: u64,
    /// Replica ports made (the first included).
    pub replica_recreations: u64,
    /// Two serve instances heard with this source name at once (hex ids): an error.
    pub two_sources: Vec<String>,
    /// Times the replica went into the error state (source unreachable or failed).
    pub outages: u64,
    /// Why the mirror is in error, if it is (a replica it cannot make, two sources).
    pub error: Option<String>,
    /// Source CLOCK_MONOTONIC minus local CLOCK_MONOTONIC (ns), estimated.
    pub clock_offset_ns: Option<i64>,
    /// Uncertainty of that estimate (ns): half the best round trip.
    pub clock_uncertainty_ns: Option<u64>,
    /// Source clock rate relative to ours minus 1, in parts per million.
    pub clock_drift_ppm: Option<f64>,
    /// Clock probe answers refused (malformed, or contradicting the others).
    pub clock_replies_refused: u64,
    /// Status-file writes that failed.
    pub status_write_failures: u64,
    /// Replica state.
    pub state: String,
}

/// A log line of one kind at most every [`LOG_EVERY_NS`]; the ones held back are counted and
/// said with the next.
#[derive(Debug, Default)]
pub struct LogLimit {
    last_ns: Option<u64>,
    held: u64,
}

impl LogLimit {
    /// Whether to log now; `Some(n)`: log, saying that `n` similar lines were held back.
    pub fn allow(&mut self, now: u64) -> Option<u64> {
        if self.last_ns.is_some_and(|l| now.saturating_sub(l) < LOG_EVERY_NS) {
            self.held += 1;
            return None;
        }
        self.last_ns = Some(now);
        Some(std::mem::take(&mut self.held))
    }
}

fn held(n: u64) -> String {
    if n == 0 {
        String::new()
    } else {
        format!(" ({n} more like it not logged)")
    }
}

/// The replica and what it follows.
struct Replica {
    writer: Writer,
    source_epoch: u64,
    geometry: Geometry,
    expected: u64,
    last_source_lost: u64,
    /// When the last chunk was applied (local ns).
    last_chunk_ns: u64,
    /// Its first frame's capture time (source CLOCK_MONOTONIC ns; 0 = not stamped).
    last_mono_ns: u64,
    /// First applied chunk (frame, source mono ns) for the rate estimate.
    anchor: Option<(u64, u64)>,
}

/// A source state waiting for confirmation (no chunk of the followed stream after it).
struct PendingState {
    state: SourceState,
    at_ns: u64,
}

/// Log limits, one per kind.
#[derive(Default)]
struct Logs {
    invalid: LogLimit,
    far: LogLimit,
    epochs: LogLimit,
    two: LogLimit,
    create: LogLimit,
    states: LogLimit,
}

/// The mirror's state: replica, followed stream, counters.
pub struct Core {
    port_path: PathBuf,
    bounds: Bounds,
    replica: Option<Replica>,
    /// The status (counters, error); `last_frame_index` and `state` are refreshed by [`Core::refresh`].
    pub st: MirrorStatus,
    /// The replica is in the error state for the source (outage, source error).
    in_error: bool,
    /// Last chunk of the followed stream, state message or liveliness sign (local ns).
    pub last_heard_ns: u64,
    /// Followed serve instance and when its last chunk came.
    followed: Option<(u64, u64)>,
    /// Another instance heard while the followed one was (id, last heard).
    other: Option<(u64, u64)>,
    /// Times of the replica creations within the last minute.
    creations: VecDeque<u64>,
    /// Last failed replica creation (local ns).
    failed_at: Option<u64>,
    pending_state: Option<PendingState>,
    logs: Logs,
    /// When the last chunk applied was queued (source clock) and when it arrived (local).
    last_stamp: Option<(u64, u64)>,
    /// The current silence of the source was said.
    unreachable_said: bool,
    /// The followed instance's liveliness token went away.
    followed_token_gone: bool,
}

/// What [`Core::on_chunk`] did with a chunk (for tests and the property test).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Published (data or a source GAP chunk), with `gap` frames of GAP before it.
    Applied {
        /// Frames published as lost before it.
        gap: u64,
        /// A new replica port was made for it.
        new_replica: bool,
    },
    /// Behind the expected frame.
    LateOrDuplicate,
    /// Outside the bounds.
    Invalid,
    /// Too far ahead.
    FarFrame,
    /// Rate limit of new replicas.
    RefusedEpoch,
    /// A second instance.
    OtherSource,
    /// The replica could not be made or written.
    Failed,
}

impl Core {
    /// A mirror writing its replica at `port_path`, within `bounds`.
    pub fn new(port_path: PathBuf, bounds: Bounds, st: MirrorStatus, now: u64) -> Core {
        Core {
            port_path,
            bounds,
            replica: None,
            st: MirrorStatus { state: "idle".into(), ..st },
            in_error: false,
            last_heard_ns: now,
            followed: None,
            other: None,
            creations: VecDeque::new(),
            failed_at: None,
            pending_state: None,
            logs: Logs::default(),
            last_stamp: None,
            unreachable_said: false,
            followed_token_gone: false,
        }
    }

    /// One Zenoh message of chunks; `offset` is the clock estimate (source - local, ns).
    pub fn on_message(&mut self, bytes: &[u8], now: u64, offset: Option<i64>) -> Vec<Outcome> {
        match wire::decode_batch(bytes) {
            Ok(chunks) => chunks.into_iter().map(|c| self.on_chunk(c, now, offset)).collect(),
            Err(e) => {
                self.st.invalid_messages += 1;
                if let Some(n) = self.logs.invalid.allow(now) {
                    tracing::warn!("refused a message: {}{}", escape(&e.to_string()), held(n));
                }
                vec![Outcome::Invalid]
            }
        }
    }

    /// The source stamp and local arrival time of the last chunk applied, once (for the
    /// clock estimate's sanity bound, [`crate::clock::Fit::observe_chunk`]).
    pub fn take_stamp(&mut self) -> Option<(u64, u64)> {
        self.last_stamp.take()
    }

    /// The replica's writer, if there is one (tests).
    pub fn writer(&self) -> Option<&Writer> {
        self.replica.as_ref().map(|r| &r.writer)
    }

    fn followed_heard(&self, now: u64) -> bool {
        let silence = if self.followed_token_gone { GONE_SILENCE_NS } else { INSTANCE_SILENCE_NS };
        self.followed.is_some_and(|(_, at)| now.saturating_sub(at) < silence)
    }

    /// Follows `instance` (heard now).
    fn follow(&mut self, instance: u64, now: u64) {
        if self.followed.map(|(id, _)| id) != Some(instance) {
            self.st.source_instance = format!("{instance:016x}");
            self.followed_token_gone = false;
        }
        self.followed = Some((instance, now));
        self.last_heard_ns = now;
    }

    /// A serve instance's liveliness token (`NS/<broker>/alive/<instance>`) appeared or went
    /// away. The followed instance's going away shortens the silence after which another
    /// instance is taken (a serve restart) to [`GONE_SILENCE_NS`].
    pub fn on_token(&mut self, instance: u64, alive: bool) {
        if self.followed.is_some_and(|(id, _)| id == instance) {
            self.followed_token_gone = !alive;
        }
    }

    /// One chunk.
    pub fn on_chunk(&mut self, c: wire::Chunk, now: u64, offset: Option<i64>) -> Outcome {
        let h = c.header;
        let geometry = Geometry {
            channels: u32::from(h.channels),
            sample_rate: h.sample_rate,
            frames_per_chunk: h.frames,
            chunks_on_port: h.chunks_on_port,
        };
        if let Err(why) = self.bounds.check(&geometry) {
            self.st.invalid_messages += 1;
            if self.replica.is_none() {
                self.st.error = Some(format!("cannot make the replica for this source: {why}"));
            }
            if let Some(n) = self.logs.invalid.allow(now) {
                tracing::warn!(
                    instance = format!("{:016x}", h.instance),
                    "refused a chunk message: {why}{}",
                    held(n)
                );
            }
            return Outcome::Invalid;
        }
        // One instance at a time: another one is a second source while the followed is heard.
        match self.followed {
            Some((id, _)) if id != h.instance && self.followed_heard(now) => {
                self.st.refused_other_source += 1;
                self.two_sources(id, h.instance, now);
                return Outcome::OtherSource;
            }
            Some((id, _)) if id == h.instance => {
                self.followed = Some((id, now));
                self.last_heard_ns = now;
            }
            _ => {}
        }
        let same = self.replica.as_ref().is_some_and(|r| r.source_epoch == h.epoch && r.geometry == geometry);
        let switching = self.followed.is_some_and(|(id, _)| id != h.instance);
        let mut new_replica = false;
        if !same {
            // A new acquisition upstream (or the first chunk): a new replica port, rate-limited.
            if let Some(o) = self.make_replica(&h, geometry, now) {
                return o;
            }
            new_replica = true;
        } else if switching {
            tracing::info!(
                instance = format!("{:016x}", h.instance),
                "new serve instance (the one followed went silent), same epoch: the port is kept"
            );
            if let Some(r) = self.replica.as_mut() {
                r.last_source_lost = 0;
            }
        }

        let Some(r) = self.replica.as_mut() else { return Outcome::Failed };
        if h.first_frame < r.expected {
            self.st.late_or_duplicate += 1;
            self.follow(h.instance, now);
            return Outcome::LateOrDuplicate;
        }
        // Ahead by more than the time allows (plus a window and a margin): refused, so that
        // one forged chunk far ahead cannot make every real one "late". The time: since the
        // last chunk arrived, or — when the clock estimate says where the source's clock is
        // now — since the last chunk's first frame was captured (a backlog of late chunks on
        // a congested link must not make the next fresh one look too far ahead).
        if !new_replica {
            let rate = u128::from(r.geometry.sample_rate);
            let margin = u128::from(AHEAD_MARGIN_NS) * rate / u128::from(SEC)
                + u128::from(r.writer.layout().frames_on_port);
            let elapsed = now.saturating_sub(r.last_chunk_ns);
            let by_arrival = u128::from(elapsed) * rate / u128::from(SEC);
            let by_clock = match offset {
                Some(off) if r.last_mono_ns != 0 => {
                    let source_now = i128::from(now) + i128::from(off);
                    let since = (source_now - i128::from(r.last_mono_ns)).max(0) as u128;
                    // Frames since the last chunk's first frame, less that chunk's own.
                    (since * rate / u128::from(SEC)).saturating_sub(u128::from(h.frames))
                }
                _ => 0,
            };
            let allowed = by_arrival.max(by_clock) + margin;
            if u128::from(h.first_frame - r.expected) > allowed {
                self.st.refused_far_frames += 1;
                if let Some(n) = self.logs.far.allow(now) {
                    tracing::warn!(
                        "refused a chunk at frame {} (expected {}): further ahead than the time since the last \
                         chunk allows ({:.1} s since it arrived){}",
                        h.first_frame,
                        r.expected,
                        elapsed as f64 / 1e9,
                        held(n)
                    );
                }
                return Outcome::FarFrame;
            }
        }
        self.follow(h.instance, now);
        // A chunk of the followed stream: a state that arrived before it is not the source's.
        if let Some(p) = self.pending_state.take() {
            self.st.refused_states += 1;
            if let Some(n) = self.logs.states.allow(now) {
                tracing::warn!(
                    "ignored a source state {:?}: the source's chunks went on after it{}",
                    escape(&p.state.state),
                    held(n)
                );
            }
        }
        let Some(r) = self.replica.as_mut() else { return Outcome::Failed };
        match publish(r, &mut self.st, &c, now, offset) {
            Ok(gap) => {
                // When it was queued (not its first frame's time, a chunk earlier or more).
                self.last_stamp = (h.send_mono_ns != 0).then_some((h.send_mono_ns, now));
                if self.in_error {
                    r.writer.set_state(State::Capturing, error_code::NONE, "");
                    self.in_error = false;
                    tracing::info!("source {:?} back: replica capturing again", self.st.source);
                }
                Outcome::Applied { gap, new_replica }
            }
            Err(e) => {
                self.st.error = Some(format!("writing the replica: {e}"));
                if let Some(n) = self.logs.create.allow(now) {
                    tracing::error!("writing the replica: {e}{}", held(n));
                }
                // A replica that cannot be written is made again on a later chunk.
                self.replica = None;
                self.failed_at = Some(now);
                Outcome::Failed
            }
        }
    }

    /// Makes the replica for a chunk of a new stream; `Some(outcome)` if it was not made.
    fn make_replica(&mut self, h: &wire::Header, geometry: Geometry, now: u64) -> Option<Outcome> {
        while self.creations.front().is_some_and(|&t| now.saturating_sub(t) >= 60 * SEC) {
            self.creations.pop_front();
        }
        let too_soon = self.creations.back().is_some_and(|&t| now.saturating_sub(t) < RECREATION_INTERVAL_NS);
        if too_soon || self.creations.len() >= RECREATIONS_PER_MINUTE {
            self.st.refused_epochs += 1;
            if let Some(n) = self.logs.epochs.allow(now) {
                tracing::warn!(
                    epoch = h.epoch,
                    instance = format!("{:016x}", h.instance),
                    "refused a new source epoch: more than one new replica a second or {RECREATIONS_PER_MINUTE} a minute{}",
                    held(n)
                );
            }
            return Some(Outcome::RefusedEpoch);
        }
        if self.failed_at.is_some_and(|t| now.saturating_sub(t) < RETRY_NS) {
            return Some(Outcome::Failed);
        }
        let params = PortParams {
            geometry: geometry.clone(),
            device: format!("bass-bridge mirror of {} (source epoch {})", self.st.source, h.epoch),
            group: None,
        };
        // The old replica stays until the new one is in place (it is superseded then).
        let made = Writer::create_at(&self.port_path, &params).and_then(|mut w| {
            w.start_at(h.first_frame)?;
            Ok(w)
        });
        let writer = match made {
            Ok(w) => w,
            Err(e) => {
                let msg = format!("cannot make the replica port {}: {e}", self.port_path.display());
                if let Some(n) = self.logs.create.allow(now) {
                    tracing::error!("{msg}; trying again on a later message{}", held(n));
                }
                self.st.error = Some(escape(&msg));
                self.failed_at = Some(now);
                return Some(Outcome::Failed);
            }
        };
        self.failed_at = None;
        self.creations.push_back(now);
        self.st.replica_recreations += 1;
        if self.st.error.as_deref().is_some_and(|e| e.starts_with("cannot make") || e.starts_with("writing"))
        {
            self.st.error = None;
        }
        tracing::info!(epoch = h.epoch, replica_epoch = writer.epoch(), first = h.first_frame, "new replica");
        self.st.replica_epoch = writer.epoch();
        self.st.source_epoch = h.epoch;
        self.in_error = false;
        self.pending_state = None;
        self.replica = Some(Replica {
            writer,
            source_epoch: h.epoch,
            geometry,
            expected: h.first_frame,
            last_source_lost: h.source_lost,
            last_chunk_ns: now,
            last_mono_ns: 0,
            anchor: None,
        });
        None
    }

    fn two_sources(&mut self, followed: u64, other: u64, now: u64) {
        self.other = Some((other, now));
        let ids = vec![format!("{followed:016x}"), format!("{other:016x}")];
        let msg = format!(
            "two sources named {:?} on this network: serve instances {} (followed) and {} \
             (refused); give one of them another --name",
            self.st.source, ids[0], ids[1]
        );
        if self.st.two_sources != ids {
            self.st.two_sources = ids;
            if let Some(r) = self.replica.as_ref().filter(|_| !self.in_error) {
                // Said on the port too, without changing its state: the followed source goes on.
                r.writer.set_state(r.writer.state(), error_code::NONE, &escape(&msg));
            }
        }
        self.st.error = Some(escape(&msg));
        if let Some(n) = self.logs.two.allow(now) {
            tracing::error!("{}{}", escape(&msg), held(n));
        }
    }

    /// A source state message (JSON of [`SourceState`]).
    pub fn on_state(&mut self, bytes: &[u8], now: u64) {
        self.last_heard_ns = now;
        let Ok(s) = serde_json::from_slice::<SourceState>(bytes) else {
            self.st.invalid_messages += 1;
            return;
        };
        let Some(r) = &self.replica else { return };
        if s.epoch != 0 && s.epoch != r.source_epoch {
            return; // another acquisition: its first chunk makes a new replica.
        }
        // Another instance's state (a second source, or a forgery): not the followed source's.
        let followed = self.followed.map(|(id, _)| format!("{id:016x}"));
        if !s.instance.is_empty() && followed.is_some_and(|f| f != s.instance) {
            self.st.refused_states += 1;
            return;
        }
        if matches!(s.state.as_str(), "error" | "gone" | "stopped") {
            self.pending_state = Some(PendingState { state: s, at_ns: now });
        }
    }

    /// The passing of time: pending states, the end of a two-sources period, the outage check
    /// (`timeout_ns` without any message from the source), the heartbeat. `alive`: the
    /// source's liveliness token is seen. Returns a warning to log, once per silence, when the
    /// source has been silent for `timeout_ns` (the replica goes into the error state).
    pub fn tick(&mut self, now: u64, timeout_ns: u64, alive: bool) -> Option<String> {
        if let Some(p) = self.pending_state.take_if(|p| now.saturating_sub(p.at_ns) >= STATE_CONFIRM_NS) {
            self.apply_state(&p.state);
        }
        if self.other.is_some_and(|(_, at)| now.saturating_sub(at) >= TWO_SOURCES_HOLD_NS) {
            self.other = None;
            self.st.two_sources.clear();
            if self.st.error.as_deref().is_some_and(|e| e.starts_with("two sources")) {
                self.st.error = None;
            }
            if let Some(r) = self.replica.as_ref().filter(|_| !self.in_error) {
                r.writer.set_state(r.writer.state(), error_code::NONE, "");
            }
            tracing::info!("only one source named {:?} heard again", self.st.source);
        }
        let silent = now.saturating_sub(self.last_heard_ns) > timeout_ns;
        if !silent {
            self.unreachable_said = false;
        }
        let why = if alive { "no data from the source" } else { "source unreachable (liveliness lost)" };
        let msg = format!("{why} for more than {:.1} s", timeout_ns as f64 / 1e9);
        let Some(r) = self.replica.as_ref() else {
            // No replica yet: said once per silence all the same.
            if silent && !self.unreachable_said {
                self.unreachable_said = true;
                return Some(format!("{msg}; no replica yet"));
            }
            return None;
        };
        r.writer.heartbeat();
        if silent && !self.in_error && r.writer.state() == State::Capturing {
            r.writer.set_state(State::Error, error_code::DEVICE_LOST, &msg);
            self.in_error = true;
            self.unreachable_said = true;
            self.st.outages += 1;
            return Some(format!("{msg}: replica in error"));
        }
        None
    }

    fn apply_state(&mut self, s: &SourceState) {
        let Some(r) = &self.replica else { return };
        match s.state.as_str() {
            "error" | "gone" if !self.in_error && r.writer.state() == State::Capturing => {
                let code = if s.error_code != 0 { s.error_code } else { error_code::DEVICE_LOST };
                let msg = if s.state == "gone" {
                    "the source broker is gone".to_string()
                } else {
                    format!("source: {}", escape(&s.message))
                };
                r.writer.set_state(State::Error, code, &msg);
                self.in_error = true;
                self.st.outages += 1;
                tracing::warn!("{msg}: replica in error");
            }
            "stopped" if r.writer.state() == State::Capturing => r.writer.stop(),
            _ => {}
        }
    }

    /// Refreshes the status fields read from the replica.
    pub fn refresh(&mut self) {
        if let Some(r) = &self.replica {
            self.st.last_frame_index = r.writer.last_frame_index();
            self.st.state = format!("{:?}", r.writer.state()).to_lowercase();
        }
    }

    /// Stops and removes the replica port (at exit).
    pub fn remove(&mut self) {
        if let Some(r) = self.replica.take() {
            r.writer.set_state(State::Stopped, error_code::NONE, "mirror stopped");
            let _ = r.writer.remove();
        }
    }
}

/// Publishes a chunk of the followed stream at or after the expected frame; returns the
/// frames published as lost before it.
fn publish(
    r: &mut Replica,
    st: &mut MirrorStatus,
    c: &wire::Chunk,
    now: u64,
    offset: Option<i64>,
) -> bassclient::Result<u64> {
    let h = c.header;
    let mono = match offset {
        Some(off) if h.mono_ns != 0 => (h.mono_ns as i64).saturating_sub(off).max(1) as u64,
        _ => 0,
    };
    let meta = ChunkMeta { mono_ns: mono, realtime_ns: h.realtime_ns, flags: chunk_flags::TIME_ESTIMATED };
    let missing = h.first_frame - r.expected;
    if missing > 0 {
        // The source's cumulative count says how many of them it never sent.
        let from_source = h.source_lost.saturating_sub(r.last_source_lost).min(missing);
        r.writer.publish_lost(
            missing,
            ChunkMeta { mono_ns: 0, realtime_ns: 0, flags: chunk_flags::TIME_ESTIMATED },
        )?;
        st.gap_frames_lost += missing;
        st.gap_frames_source += from_source;
    }
    r.last_source_lost = h.source_lost;
    let mut flags = meta.flags;
    if h.flags & wire::flags::DISCONTINUITY != 0 || h.flags & wire::flags::SOURCE_LOSS != 0 {
        flags |= chunk_flags::DISCONTINUITY;
    }
    if h.flags & wire::flags::GAP != 0 {
        r.writer.publish(Source::Zeros, ChunkMeta { flags: flags | chunk_flags::GAP, ..meta })?;
    } else {
        r.writer.publish(Source::Interleaved(&c.samples), ChunkMeta { flags, ..meta })?;
    }
    r.expected = h.first_frame + u64::from(h.frames);
    r.last_chunk_ns = now;
    r.last_mono_ns = h.mono_ns;
    st.chunks_written += 1;
    // The replica's rate estimate: the source's frames over the source's clock, from the
    // first chunk on (a value far from the nominal rate is a bad stamp, not a rate).
    if h.mono_ns != 0 {
        match r.anchor {
            None => r.anchor = Some((h.first_frame, h.mono_ns)),
            Some((f0, m0)) if h.mono_ns > m0 + SEC => {
                let hz = (h.first_frame - f0) as f64 * 1e9 / (h.mono_ns - m0) as f64;
                let nominal = f64::from(r.geometry.sample_rate);
                if (hz - nominal).abs() < nominal * 0.01 {
                    r.writer.set_rate_estimate(hz);
                }
            }
            Some(_) => {}
        }
    }
    Ok(missing)
}
