//! Capture devices: real ALSA PCMs ([`alsa`]), simulated ones ([`sim`]) and WAV replay
//! ([`file`]), behind one
//! small interface the capture thread drives.

pub mod alsa;
pub mod field;
pub mod file;
pub mod mcap_file;
mod regular;
pub mod sim;

use bassport::control::DeviceInfo;

pub use basskit::pacing::{sleep_until, StopSignal, CAPTURE_TIMER_SLACK_NS};

/// [`basskit::pacing::precise_timers`] for the capture thread; a refusal is logged (debug).
pub fn precise_timers() {
    if let Err(e) = basskit::pacing::precise_timers() {
        tracing::debug!("PR_SET_TIMERSLACK {CAPTURE_TIMER_SLACK_NS} ns refused: {e}");
    }
}

/// Outcome of one device read.
#[derive(Debug, PartialEq)]
pub enum ReadEvent {
    /// `frames` frames were written at the start of the buffer (interleaved S32).
    Frames {
        /// Frames read.
        frames: usize,
        /// CLOCK_MONOTONIC (ns) at which the first of them was captured.
        first_mono_ns: u64,
        /// Whether `first_mono_ns` is estimated from the sample clock rather than read from
        /// the device.
        time_estimated: bool,
        /// When the first of them was observed to be captured, for the rate estimator
        /// (for a real device the same as `first_mono_ns`).
        observed_mono_ns: u64,
        /// Whether the frames arrive late, in a catch-up burst: the device fell behind (its
        /// thread was starved), so `observed_mono_ns` says nothing about the device clock.
        late: bool,
    },
    /// An overrun happened and was recovered: frames were lost before the next read.
    Xrun,
    /// One whole chunk of a replayed recording, published as it was recorded (frames
    /// interleaved at the start of the buffer unless it is GAP).
    Chunk(RecordedChunk),
    /// No data arrived within the poll slice; the caller decides whether that is a stall.
    Idle,
    /// Nothing to publish yet, by design (a replayed recording waiting out the time of a
    /// loss): the device is alive, this is no stall.
    Pending,
    /// The stop signal fired.
    Stopped,
    /// The device failed for good (`code` is a `format::error_code`).
    Failed {
        /// `bassport::format::error_code`.
        code: u32,
        /// What happened.
        message: String,
    },
    /// The source has no more frames (the end of a replayed recording): the acquisition ends
    /// as if stopped, with `message` saying why.
    Ended {
        /// What ended.
        message: String,
        /// A recorded loss runs to the end: the port skips to this frame first
        /// (`Writer::skip_to`), so that readers count the loss.
        lost_to: Option<u64>,
    },
}

/// A chunk of a replayed recording ([`file`]): its place, flags and timestamps as recorded.
#[derive(Debug, PartialEq)]
pub struct RecordedChunk {
    /// Frame index of the chunk's first frame.
    pub first_frame: u64,
    /// The first frame readers may read: every frame before it that the port has not
    /// published yet is lost (a recording's start, or a loss of the recorder), see
    /// `Writer::skip_to`.
    pub readable_from: u64,
    /// A GAP chunk (zeros; the buffer is not read).
    pub zeros: bool,
    /// Timestamps and flags, published as they are.
    pub meta: bassport::ChunkMeta,
}

/// A configured capture device, owned by the capture thread.
pub trait Capture: Send {
    /// Starts the stream (called on the capture thread, right before the first read).
    fn start(&mut self) -> Result<(), String>;
    /// Reads up to `max_frames` frames into `out` (interleaved S32, `channels` per frame),
    /// waiting at most one poll slice for data.
    fn read(&mut self, out: &mut [i32], max_frames: usize, stop: &StopSignal) -> ReadEvent;
    /// The device sample format in use (`S32_LE` for simulated devices).
    fn format_name(&self) -> &'static str;
    /// Reopens the device after it failed (a follower of a several-device acquisition
    /// recovering) and starts it; `None`: not supported here, the caller opens the device
    /// afresh by name.
    fn reopen(&mut self) -> Option<Result<(), String>> {
        None
    }
}

/// Every capture device the broker can open: the simulated ones, then ALSA's hints.
pub fn list() -> Vec<DeviceInfo> {
    let mut v: Vec<DeviceInfo> = sim::DEVICES
        .iter()
        .map(|(k, d)| DeviceInfo { name: format!("sim:{}", k.name()), description: (*d).to_owned() })
        .collect();
    v.push(DeviceInfo {
        name: "sim:field".into(),
        description: "Simulated: a card with its own clock sampling the shared analytic sound field \
                      (sim:field?ppm=87&slew=0.5&jitter_us=200&seed=1; docs/multi-device.md)"
            .into(),
    });
    v.extend(alsa::list());
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn precise_timers_sets_the_thread_slack_to_one_ns_and_leaves_other_threads_alone() {
        let inherited = rustix::thread::current_timer_slack().expect("PR_GET_TIMERSLACK");
        let set = std::thread::spawn(|| {
            precise_timers();
            rustix::thread::current_timer_slack().expect("PR_GET_TIMERSLACK")
        })
        .join()
        .expect("thread");
        assert_eq!(set, CAPTURE_TIMER_SLACK_NS);
        assert_eq!(rustix::thread::current_timer_slack().expect("PR_GET_TIMERSLACK"), inherited);
    }

    #[test]
    fn sleep_until_returns_at_the_deadline_or_on_stop() {
        let stop = StopSignal::new().expect("eventfd");
        let deadline = bassport::sys::monotonic_ns() + 3_000_000;
        assert!(sleep_until(deadline, &stop));
        assert!(bassport::sys::monotonic_ns() >= deadline);
        stop.signal();
        assert!(!sleep_until(bassport::sys::monotonic_ns() + 10_000_000_000, &stop));
    }

    #[test]
    fn a_stop_ends_a_long_wait_and_a_short_one_ends_at_its_deadline() {
        let stop = StopSignal::new().expect("eventfd");
        std::thread::scope(|s| {
            let t0 = std::time::Instant::now();
            s.spawn(|| {
                std::thread::sleep(std::time::Duration::from_millis(50));
                stop.signal();
            });
            assert!(!sleep_until(bassport::sys::monotonic_ns() + 10_000_000_000, &stop));
            let waited = t0.elapsed();
            assert!(
                waited < std::time::Duration::from_secs(5),
                "a stop ended a 10 s wait only after {waited:?}"
            );
        });
        // A wait within one sleep (ONE_SLEEP_MAX_NS) is not cut short.
        let fresh = StopSignal::new().expect("eventfd");
        let deadline = bassport::sys::monotonic_ns() + basskit::pacing::ONE_SLEEP_MAX_NS / 2;
        assert!(sleep_until(deadline, &fresh));
        assert!(bassport::sys::monotonic_ns() >= deadline);
    }
}
