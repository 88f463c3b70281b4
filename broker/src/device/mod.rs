//! Capture devices: real ALSA PCMs ([`alsa`]), simulated ones ([`sim`]) and WAV replay
//! ([`file`]), behind one
//! small interface the capture thread drives.

pub mod alsa;
pub mod file;
pub mod sim;

use std::sync::atomic::{AtomicBool, Ordering};

use bassclient::control::DeviceInfo;

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

/// Sleeps until CLOCK_MONOTONIC `deadline` (ns) — in `poll` on the stop's eventfd while more
/// than 2 ms remain, then with an absolute-deadline sleep for the last stretch — and returns
/// false as soon as the stop fires. The pacing of the simulated and replayed devices.
pub fn sleep_until(deadline: u64, stop: &StopSignal) -> bool {
    const MS: u64 = 1_000_000;
    loop {
        if stop.is_set() {
            return false;
        }
        let now = bassclient::sys::monotonic_ns();
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
        /// `bassclient::format::error_code`.
        code: u32,
        /// What happened.
        message: String,
    },
    /// The source has no more frames (the end of a replayed recording): the acquisition ends
    /// as if stopped, with `message` saying why.
    Ended {
        /// What ended.
        message: String,
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
    pub meta: bassclient::ChunkMeta,
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
