//! The mirror's status (the `--status-file` JSON and the counters in the log) and the rate
//! limit of its log lines.

use serde::Serialize;

use crate::net::BridgeState;

const SEC: u64 = 1_000_000_000;
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
    /// Messages on the source's keys without the source identity's signature (with
    /// credentials): never decoded, never written.
    pub forged_messages: u64,
    /// Whose signature every chunk and state must carry (with credentials; empty otherwise).
    pub source_identity: String,
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
    /// Uncertainty of that estimate (ns): half the overlap of the rounds' intervals (each half
    /// its round trip plus the drift's possible error over its age; [`crate::clock::Fit::at`]).
    pub clock_uncertainty_ns: Option<u64>,
    /// Source clock rate relative to ours minus 1, in parts per million.
    pub clock_drift_ppm: Option<f64>,
    /// Clock probe answers refused (malformed, or contradicting the others).
    pub clock_replies_refused: u64,
    /// Status-file writes that failed.
    pub status_write_failures: u64,
    /// Replica state (`idle` before the first replica).
    pub state: BridgeState,
    /// Whether the source was heard within the timeout.
    pub link_up: bool,
    /// CLOCK_MONOTONIC (ns) of the last change of `link_up` (the mirror's start before one).
    #[serde(skip)]
    pub link_since_ns: u64,
    /// The source's last known state (from its state messages and chunks).
    pub source_state: BridgeState,
    /// The newest source frame heard of.
    pub source_last_frame_index: u64,
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

/// What to add to a log line when `n` like it were held back.
pub fn held(n: u64) -> String {
    if n == 0 {
        String::new()
    } else {
        format!(" ({n} more like it not logged)")
    }
}
