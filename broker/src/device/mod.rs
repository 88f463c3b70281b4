//! Capture devices: real ALSA PCMs ([`alsa`]), simulated ones ([`sim`]) and WAV replay
//! ([`file`]), behind one
//! small interface the capture thread drives.

pub mod alsa;
pub mod file;
pub mod mcap_file;
mod regular;
pub mod sim;

use std::sync::atomic::{AtomicBool, Ordering};

use bassport::control::DeviceInfo;

use crate::os::EventFd;

/// Asks a capture thread to stop: a flag for loops that sleep, an eventfd for loops that poll.
pub struct StopSignal {
    flag: AtomicBool,
    efd: EventFd,
}

impl StopSignal {
    /// A fresh, unsignalled stop signal.
    pub fn new() -> std::io::Result<StopSignal> {
        Ok(StopSignal { flag: AtomicBool::new(false), efd: EventFd::new()? })
    }

    /// Signals the stop (idempotent).
    pub fn signal(&self) {
        self.flag.store(true, Ordering::Release);
        self.efd.signal();
    }

    /// Whether the stop was signalled.
    pub fn is_set(&self) -> bool {
        self.flag.load(Ordering::Acquire)
    }

    /// The eventfd, readable once the stop is signalled.
    pub fn fd(&self) -> std::os::fd::RawFd {
        self.efd.raw()
    }
}

/// Timer slack of the capture thread, in ns: the kernel may delay a timed wake-up of the
/// thread by up to this much, to batch it with other timers. The default (50 µs, inherited
/// from the parent thread) was the largest part of a simulated device's delay; 1 ns (the
/// smallest a thread can ask for; 0 means "the default") removes it.
pub const CAPTURE_TIMER_SLACK_NS: u64 = 1;

/// Sets the calling thread's timer slack to [`CAPTURE_TIMER_SLACK_NS`]
/// (`prctl(PR_SET_TIMERSLACK)`), so that its timed waits — [`sleep_until`]'s sleeps and polls,
/// an ALSA `poll`'s timeout — end when they are due. Called once by the capture thread. A
/// SCHED_FIFO thread has no slack anyway; this is for the capture thread that runs without.
///
/// Measured on the bench machine (2-core VM), the two-stage pacing below with 50 µs slack:
/// wake-up p50 65–74 µs after the deadline; with 1 ns: 13–21 µs, at the same CPU per wake.
/// An absolute `timerfd` polled with the stop's eventfd (no slack by construction, one wake-up
/// instead of two) used 5–6 µs less CPU per wait but woke 38–60 µs late: the vCPU sleeps
/// through the whole period and wakes from a deeper idle state, while the last 1 ms stretch of
/// [`sleep_until`] finds it lightly idle. So the pacing keeps its two stages, without slack.
pub fn precise_timers() {
    let slack = std::num::NonZeroU64::new(CAPTURE_TIMER_SLACK_NS);
    if let Err(e) = rustix::thread::set_current_timer_slack(slack) {
        tracing::debug!("PR_SET_TIMERSLACK {CAPTURE_TIMER_SLACK_NS} ns refused: {e}");
    }
}

/// Sleeps until CLOCK_MONOTONIC `deadline` (ns) — in `poll` on the stop's eventfd while more
/// than 2 ms remain, then with an absolute-deadline sleep for the last stretch — and returns
/// false as soon as the stop fires. The pacing of the simulated and replayed devices; called
/// on the capture thread, whose timer slack [`precise_timers`] has set to 1 ns, so the last
/// stretch ends within µs of the deadline.
pub fn sleep_until(deadline: u64, stop: &StopSignal) -> bool {
    const MS: u64 = 1_000_000;
    loop {
        if stop.is_set() {
            return false;
        }
        let now = bassport::sys::monotonic_ns();
        if now >= deadline {
            return true;
        }
        let remaining = deadline - now;
        if remaining > 2 * MS {
            let mut fds = [crate::os::pollin(stop.fd())];
            let _ = crate::os::poll(&mut fds, Some(std::time::Duration::from_nanos(remaining - MS)));
        } else {
            crate::os::sleep_until_mono(deadline);
        }
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
}

/// Every capture device the broker can open: the simulated ones, then ALSA's hints.
pub fn list() -> Vec<DeviceInfo> {
    let mut v: Vec<DeviceInfo> = sim::DEVICES
        .iter()
        .map(|(k, d)| DeviceInfo { name: format!("sim:{}", k.name()), description: (*d).to_owned() })
        .collect();
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
}
