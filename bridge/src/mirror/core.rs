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

use bassport::control::{ReplicaStatus, Status};
use bassport::format::error_code;
use bassport::{State, Writer};

use super::bounds::Bounds;
use super::replica::Replica;
use super::status::held;
pub use super::status::{LogLimit, MirrorStatus, LOG_EVERY_NS};
use crate::clock::ClockMap;
use crate::net::{BridgeState, SourceState};
use crate::text::escape;
use crate::wire;

mod chunk;

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
    /// The group replica ports are given to (`mirror --group`).
    pub group: Option<u32>,
    bounds: Bounds,
    replica: Option<Replica>,
    /// The status (counters, error); `last_frame_index` and `state` are refreshed by [`Core::refresh`].
    pub st: MirrorStatus,
    /// The replica is in the error state for the source (outage, source error).
    in_error: bool,
    /// Why the replica last went into the error state: the status's `error` while it is
    /// there and the mirror has no error of its own ([`Core::refresh`]).
    error_state: Option<String>,
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
    /// The decoded samples of the chunk being written (reused: no allocation per chunk).
    samples: Vec<i32>,
    /// What [`Core::on_message`] did with each chunk of the last message (reused).
    outcomes: Vec<Outcome>,
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

/// A state name as the control protocol's Status gives it.
fn bridge_state_name(s: BridgeState) -> String {
    serde_json::to_value(s).ok().and_then(|v| v.as_str().map(str::to_owned)).unwrap_or_default()
}

impl Core {
    /// The Status a replica's control socket answers by itself: the replica port's state and
    /// geometry, and what the mirror knows of the link and the source ([`ReplicaStatus`]).
    pub fn control_status(&self, now: u64) -> Status {
        let st = &self.st;
        let mut s = Status {
            broker_pid: std::process::id(),
            broker_version: env!("CARGO_PKG_VERSION").to_owned(),
            device: format!("replica of {}", st.source),
            ..Status::default()
        };
        if let Some(r) = &self.replica {
            let g = r.writer.geometry();
            s.state = r.writer.state() as u32;
            (s.sample_rate, s.frames_per_chunk, s.chunks_on_port, s.channels) =
                (g.sample_rate, g.frames_per_chunk, g.chunks_on_port, g.channels);
            s.epoch = r.writer.epoch();
            s.last_frame_index = r.writer.last_frame_index();
            s.chunks_published = st.chunks_written;
            s.gap_frames = st.gap_frames_lost;
            s.rate_estimate_hz = f64::from(g.sample_rate);
            s.port = r.writer.path().display().to_string();
            s.format = "S32_LE (replica)".to_owned();
            if s.state == State::Error as u32 {
                s.error_code = error_code::DEVICE_LOST;
            }
        }
        let since = now.saturating_sub(st.link_since_ns) as f64 / 1e9;
        let link = if st.link_up { "up" } else { "down" };
        s.message = format!(
            "replica of {}: link {link} for {since:.1} s; source {}; {} outage(s), {} frames never received",
            st.source,
            bridge_state_name(st.source_state),
            st.outages,
            st.gap_frames_lost
        );
        if let Some(e) = &st.error {
            s.message = format!("{e}; {}", s.message);
        }
        s.replica = Some(Box::new(ReplicaStatus {
            source: st.source.clone(),
            link_up: st.link_up,
            link_since_s: since,
            source_state: bridge_state_name(st.source_state),
            source_epoch: st.source_epoch,
            source_last_frame_index: st.source_last_frame_index,
            gap_frames_lost: st.gap_frames_lost,
            gap_frames_source: st.gap_frames_source,
            outages: st.outages,
            forged_messages: st.forged_messages,
            source_status: None,
        }));
        s
    }

    /// A mirror writing its replica at `port_path`, within `bounds`.
    pub fn new(port_path: PathBuf, bounds: Bounds, st: MirrorStatus, now: u64) -> Core {
        Core {
            port_path,
            group: None,
            bounds,
            replica: None,
            st: MirrorStatus { state: BridgeState::Idle, ..st },
            in_error: false,
            error_state: None,
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
            samples: Vec::new(),
            outcomes: Vec::new(),
        }
    }

    /// One Zenoh message of chunks; `clock` is the clock estimate (source - local offset and its uncertainty).
    /// Returns what was done with each chunk (one [`Outcome::Invalid`] for a refused
    /// message); nothing is allocated once the buffers have grown.
    pub fn on_message(&mut self, bytes: &[u8], now: u64, clock: Option<ClockMap>) -> &[Outcome] {
        let mut outcomes = std::mem::take(&mut self.outcomes);
        outcomes.clear();
        match wire::decode_batch(bytes) {
            Ok(chunks) => outcomes.extend(chunks.map(|c| self.on_chunk(&c, now, clock))),
            Err(e) => {
                self.st.invalid_messages += 1;
                if let Some(n) = self.logs.invalid.allow(now) {
                    tracing::warn!("refused a message: {}{}", escape(&e.to_string()), held(n));
                }
                outcomes.push(Outcome::Invalid);
            }
        }
        self.outcomes = outcomes;
        &self.outcomes
    }

    /// The source stamp and local arrival time of the last chunk applied, once (for the
    /// clock estimate's sanity bound, [`crate::clock::Fit::observe_chunk`]).
    pub fn take_stamp(&mut self) -> Option<(u64, u64)> {
        self.last_stamp.take()
    }

    /// The serve instance followed, if any.
    pub fn followed_instance(&self) -> Option<u64> {
        self.followed.map(|(id, _)| id)
    }

    /// A message on the source's keys without its signature: dropped, counted, logged (rate
    /// limited). `what`: chunks or state.
    pub fn on_forged(&mut self, what: &str, now: u64) {
        self.st.forged_messages += 1;
        if let Some(n) = self.logs.invalid.allow(now) {
            tracing::warn!(
                "refused a {what} message not signed by the source identity {:?}{}",
                self.st.source_identity,
                held(n)
            );
        }
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
        self.st.source_state = s.state;
        self.st.source_last_frame_index = self.st.source_last_frame_index.max(s.last_frame_index);
        if matches!(s.state, BridgeState::Error | BridgeState::Gone | BridgeState::Stopped) {
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
        if self.st.link_since_ns == 0 || self.st.link_up == silent {
            self.st.link_up = !silent;
            self.st.link_since_ns = now;
        }
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
            self.error_state = Some(msg.clone());
            self.unreachable_said = true;
            self.st.outages += 1;
            return Some(format!("{msg}: replica in error"));
        }
        None
    }

    fn apply_state(&mut self, s: &SourceState) {
        let Some(r) = &self.replica else { return };
        match s.state {
            BridgeState::Error | BridgeState::Gone
                if !self.in_error && r.writer.state() == State::Capturing =>
            {
                let code = if s.error_code != 0 { s.error_code } else { error_code::DEVICE_LOST };
                let msg = if s.state == BridgeState::Gone {
                    "the source broker is gone".to_string()
                } else {
                    format!("source: {}", escape(&s.message))
                };
                r.writer.set_state(State::Error, code, &msg);
                self.in_error = true;
                self.error_state = Some(msg.clone());
                self.st.outages += 1;
                tracing::warn!("{msg}: replica in error");
            }
            BridgeState::Stopped if r.writer.state() == State::Capturing => r.writer.stop(),
            _ => {}
        }
    }

    /// Refreshes the status fields read from the replica, and the error: the mirror's own
    /// (a replica it cannot make or write, two sources), else, while the replica is in the
    /// error state, why it went there (the outage, the source's error), else none.
    pub fn refresh(&mut self) {
        if let Some(r) = &self.replica {
            self.st.last_frame_index = r.writer.last_frame_index();
            self.st.state = BridgeState::of_port(Some(r.writer.state()));
        }
        let shows_error_state = self.st.error.is_some() && self.st.error == self.error_state;
        if self.in_error && self.st.error.is_none() {
            self.st.error = self.error_state.clone();
        } else if !self.in_error && shows_error_state {
            self.st.error = None;
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
