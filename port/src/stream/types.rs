//! What a stream is configured with and what its callbacks receive.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Where a stream starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// The oldest frame still in the window.
    Oldest,
    /// The next frame to be published (the live edge).
    Now,
    /// A given frame (frames already gone are reported as lost before the first block).
    Frame(u64),
}

/// How a block's samples are laid out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleLayout {
    /// One slice per channel ([`Block::channel`]).
    Planar,
    /// One slice, frame after frame ([`Block::interleaved`]).
    Interleaved,
}

/// What a stream delivers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Config {
    /// Frames per block (0: one chunk, nFramesPerChunk); at most the port's window (nFOP).
    pub frames_per_call: usize,
    /// The first frame.
    pub start: Start,
    /// The port's channels wanted, in the order wanted (empty: all).
    pub channels: Vec<u32>,
    /// Planar or interleaved samples.
    pub layout: SampleLayout,
    /// `SCHED_FIFO` priority for the thread that runs the stream (None: leave it as it is).
    /// Refused (no `CAP_SYS_NICE`, no rtprio limit): [`Event::RealtimeRefused`], and the
    /// stream goes on at its normal priority.
    pub realtime_priority: Option<i32>,
}

impl Default for Config {
    fn default() -> Config {
        Config {
            frames_per_call: 0,
            start: Start::Now,
            channels: Vec::new(),
            layout: SampleLayout::Planar,
            realtime_priority: None,
        }
    }
}

impl Config {
    /// This configuration starting at the oldest frame in the window.
    pub fn oldest(mut self) -> Config {
        self.start = Start::Oldest;
        self
    }
}

/// What a callback tells the stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Control {
    /// Go on.
    Continue,
    /// End the stream ([`Stream::run`] returns `Ok`).
    Stop,
}

/// One block of frames, valid during the callback.
#[derive(Debug)]
pub struct Block<'a> {
    /// Acquisition epoch the frames belong to.
    pub epoch: u64,
    /// Absolute index of the first frame (frames are numbered from 1 in each epoch).
    pub first_frame: u64,
    /// Frames in the block (`frames_per_call`, fewer only at the end of an acquisition).
    pub frames: usize,
    /// Frames lost between the previous block (or the start) and this one.
    pub lost: u64,
    /// `format::chunk_flags` (GAP, DISCONTINUITY, TIME_ESTIMATED, LATE) OR-ed over the
    /// chunks the block covers.
    pub flags: u32,
    /// CLOCK_MONOTONIC (ns) of the first frame: its chunk's time plus the offset at `rate_hz`.
    pub mono_ns: u64,
    /// CLOCK_REALTIME (ns) of the first frame.
    pub realtime_ns: u64,
    /// The writer's device-rate estimate in Hz (the nominal rate until there is one).
    pub rate_hz: f64,
    pub(super) channels: &'a [u32],
    pub(super) planar: &'a [Vec<i32>],
    pub(super) interleaved: &'a [i32],
    pub(super) offset: usize,
    pub(super) layout: SampleLayout,
}

impl<'a> Block<'a> {
    /// The port channels of the block, in the block's order.
    pub fn channels(&self) -> &'a [u32] {
        self.channels
    }

    /// The samples of the block's `k`-th channel (planar streams; None if interleaved).
    pub fn channel(&self, k: usize) -> Option<&'a [i32]> {
        match self.layout {
            SampleLayout::Planar => self.planar.get(k).map(|b| &b[self.offset..self.offset + self.frames]),
            SampleLayout::Interleaved => None,
        }
    }

    /// The interleaved samples, `frames × channels` (interleaved streams; None if planar).
    pub fn interleaved(&self) -> Option<&'a [i32]> {
        match self.layout {
            SampleLayout::Interleaved => Some(&self.interleaved[..self.frames * self.channels.len()]),
            SampleLayout::Planar => None,
        }
    }

    /// Sample `i` of the block's `k`-th channel, in either layout.
    pub fn sample(&self, k: usize, i: usize) -> i32 {
        match self.layout {
            SampleLayout::Planar => self.planar[k][self.offset + i],
            SampleLayout::Interleaved => self.interleaved[i * self.channels.len() + k],
        }
    }
}

/// Something that happened to the stream's acquisition.
#[derive(Clone, Debug, PartialEq)]
pub enum Event<'a> {
    /// The acquisition was stopped; `last` is its last frame (every frame up to it was
    /// delivered or counted lost). Continue: wait for it to go on ([`Event::Resumed`]) or for
    /// a new acquisition ([`Event::Restarted`]).
    Stopped {
        /// The last frame.
        last: u64,
    },
    /// A new acquisition replaced the port; the stream goes on from `resume_at` (its oldest
    /// frame) in `epoch`. Reopening the port is the one step of a stream that allocates.
    Restarted {
        /// The new epoch.
        epoch: u64,
        /// The first frame the stream reads in it.
        resume_at: u64,
    },
    /// The acquisition ended on a device error (`format::error_code`). Continue: wait for it
    /// to go on (a broker restarted by its service manager takes the port back:
    /// [`Event::Resumed`]) or for a new acquisition ([`Event::Restarted`]).
    Device {
        /// `format::error_code`.
        code: u32,
        /// The writer's message.
        message: &'a str,
    },
    /// The writer process is gone (dead, and no successor took the port back within the
    /// port's restart grace; or a writer of another pid namespace silent for too long).
    /// Continue: wait for the acquisition to go on ([`Event::Resumed`]) or for a new one.
    WriterGone {
        /// Its pid.
        pid: u32,
    },
    /// After [`Event::Stopped`], [`Event::Device`] or [`Event::WriterGone`]: the same
    /// acquisition goes on in the same port and epoch (a successor broker took the port back,
    /// the writer is alive again). The stream goes on from `resume_at`, the frame after the
    /// last one delivered: frames that left the window meanwhile are the next block's `lost`,
    /// the frames the writer missed come as zero frames flagged GAP.
    Resumed {
        /// The epoch (the same as before the end).
        epoch: u64,
        /// The next frame the stream reads.
        resume_at: u64,
    },
    /// `SCHED_FIFO` was refused (`errno`, e.g. EPERM); the stream runs at its normal priority.
    RealtimeRefused {
        /// The errno of `sched_setscheduler`.
        errno: i32,
    },
}

/// Stops a stream from any thread (also from inside its callbacks).
#[derive(Clone, Debug)]
pub struct Stopper(pub(super) Arc<AtomicBool>);

impl Stopper {
    /// Asks the stream to stop: no block starts after this returns; a stream waiting for
    /// frames notices within [`STOP_SLICE`].
    pub fn stop(&self) {
        self.0.store(true, Ordering::Release);
    }

    /// Whether a stop was asked.
    pub fn is_stopped(&self) -> bool {
        self.0.load(Ordering::Acquire)
    }
}
