//! The lock-free window: one writer, many passive readers (Aeron broadcast style).
//!
//! Writer, per chunk: store the write intent (the newest frame it is about to
//! write), `fence(Release)`, store the samples (Relaxed), then publish
//! `last_frame_index` (Release).
//!
//! Reader: load `last_frame_index` (Acquire), run the formal `getAudioData`
//! algorithm of the BASS documentation on that snapshot, copy the samples
//! (Relaxed), `fence(Acquire)`, load the write intent. A frame `f` with
//! `f + nFOP <= intent` shares its slot with a frame the writer may have been
//! writing during the copy: it is dropped and counted as loss. So a reader never
//! delivers a torn frame, and always `delivered + loss = nfr_out - nfr_in`.
//!
//! This file only uses `crate::sync::atomic`, so the loom model in
//! `tests/loom_ring.rs` compiles it against loom's atomics unchanged.

use crate::sync::atomic::{fence, AtomicI32, AtomicU64, Ordering};

/// Views of the shared window's protocol words and samples.
pub struct Ring<'a> {
    /// Newest published frame.
    pub last_frame_index: &'a AtomicU64,
    /// Newest frame the writer may be writing.
    pub write_intent: &'a AtomicU64,
    /// Channel-planar rings, `channels * frames_on_port` samples.
    pub samples: &'a [AtomicI32],
    /// nFOP.
    pub frames_on_port: u64,
}

/// What one read returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadOutcome {
    /// Frames copied into the outputs (`n`).
    pub frames: usize,
    /// The updated next frame to read (`nfr`).
    pub next_frame: u64,
    /// Frames that left the window before they could be read.
    pub loss: u64,
}

/// Samples for one publish.
pub enum Source<'s> {
    /// Frame-interleaved samples, `channels * count` of them.
    Interleaved(&'s [i32]),
    /// One slice of `count` samples per channel.
    Planar(&'s [&'s [i32]]),
    /// Zero frames (a device gap).
    Zeros,
}

/// Snapshot of the window taken by a reader before copying.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Plan {
    /// First frame to copy (after a loss jump).
    pub first: u64,
    /// Frames to copy.
    pub frames: usize,
    /// Frames lost before `first`.
    pub loss: u64,
}

impl<'a> Ring<'a> {
    /// Channel `c`'s ring.
    #[inline]
    pub fn channel(&self, c: usize) -> &'a [AtomicI32] {
        let n = self.frames_on_port as usize;
        &self.samples[c * n..(c + 1) * n]
    }

    /// Ring slot of `frame`.
    #[inline]
    fn slot(&self, frame: u64) -> usize {
        ((frame + self.frames_on_port - 1) % self.frames_on_port) as usize
    }

    /// Publishes `count` frames after frame `lfi`, the current last frame index (writer only,
    /// which owns that value; `count <= nFOP`). Returns the new last frame index.
    ///
    /// `under_intent` runs after the intent is announced and before the frames are
    /// published: the writer updates the chunk table there.
    pub fn publish(
        &self,
        lfi: u64,
        count: usize,
        channels: usize,
        src: &Source<'_>,
        under_intent: impl FnOnce(),
    ) -> u64 {
        let new_lfi = lfi + count as u64;
        // Announce the frames about to be overwritten before touching any sample.
        self.write_intent.store(new_lfi, Ordering::Relaxed);
        fence(Ordering::Release);
        under_intent();
        let mut done = 0usize;
        while done < count {
            let start = self.slot(lfi + 1 + done as u64);
            let len = (count - done).min(self.frames_on_port as usize - start);
            for c in 0..channels {
                let dst = &self.channel(c)[start..start + len];
                match src {
                    Source::Interleaved(s) => {
                        for (i, d) in dst.iter().enumerate() {
                            d.store(s[(done + i) * channels + c], Ordering::Relaxed);
                        }
                    }
                    Source::Planar(p) => {
                        for (d, v) in dst.iter().zip(&p[c][done..done + len]) {
                            d.store(*v, Ordering::Relaxed);
                        }
                    }
                    Source::Zeros => {
                        for d in dst {
                            d.store(0, Ordering::Relaxed);
                        }
                    }
                }
            }
            done += len;
        }
        self.last_frame_index.store(new_lfi, Ordering::Release);
        new_lfi
    }

    /// The formal `getAudioData` algorithm on a snapshot `lfi`, without copying.
    ///
    /// `ofi = max(0, lfi - nFOP + 1)`; `nfr < ofi` is a loss that moves `nfr`
    /// to `ofi`; then up to `max` frames from `nfr` to `lfi` are available.
    #[inline]
    pub fn plan(&self, lfi: u64, max: usize, nfr: u64) -> Plan {
        let ofi = (lfi + 1).saturating_sub(self.frames_on_port);
        let (first, loss) = if nfr < ofi { (ofi, ofi - nfr) } else { (nfr, 0) };
        let avail = if first <= lfi { lfi - first + 1 } else { 0 };
        let frames = avail.min(max as u64) as usize;
        Plan { first, frames, loss }
    }

    /// First frame that cannot have been overwritten when the writer's intent is `intent`.
    ///
    /// Saturating: a hostile header's intent of 2^64 - 1 must neither overflow (a panic in
    /// debug builds) nor wrap to 0 (which would vouch for every frame).
    #[inline]
    pub fn first_intact(&self, intent: u64) -> u64 {
        intent.saturating_add(1).saturating_sub(self.frames_on_port)
    }

    /// Copies `frames` frames from `first` for channel `c` into `dst` (Relaxed loads).
    #[inline]
    pub fn copy_channel(&self, c: usize, first: u64, frames: usize, dst: &mut [i32]) {
        let ring = self.channel(c);
        let mut done = 0usize;
        while done < frames {
            let start = self.slot(first + done as u64);
            let len = (frames - done).min(self.frames_on_port as usize - start);
            for (d, s) in dst[done..done + len].iter_mut().zip(&ring[start..start + len]) {
                *d = s.load(Ordering::Relaxed);
            }
            done += len;
        }
    }

    /// Reads up to `max` frames from `nfr` into `out` (one slice per channel,
    /// channels `0..out.len()`, each at least `min(max, nFOP)` long).
    ///
    /// `lfi` is the caller's Acquire load of `last_frame_index`.
    pub fn read(&self, lfi: u64, max: usize, nfr: u64, out: &mut [&mut [i32]]) -> ReadOutcome {
        self.read_impl(lfi, max, nfr, out, true)
    }

    /// The known-bad variant for the loom model: no re-check of the intent after the copy.
    #[cfg(loom)]
    pub fn read_without_recheck(
        &self,
        lfi: u64,
        max: usize,
        nfr: u64,
        out: &mut [&mut [i32]],
    ) -> ReadOutcome {
        self.read_impl(lfi, max, nfr, out, false)
    }

    #[inline(always)]
    fn read_impl(
        &self,
        lfi: u64,
        max: usize,
        nfr: u64,
        out: &mut [&mut [i32]],
        recheck: bool,
    ) -> ReadOutcome {
        let plan = self.plan(lfi, max, nfr);
        for (c, dst) in out.iter_mut().enumerate() {
            self.copy_channel(c, plan.first, plan.frames, dst);
        }
        let end = plan.first + plan.frames as u64;
        let mut outcome = ReadOutcome { frames: plan.frames, next_frame: end, loss: plan.loss };
        if !recheck || plan.frames == 0 {
            return outcome;
        }
        fence(Ordering::Acquire);
        let intact = self.first_intact(self.write_intent.load(Ordering::Relaxed));
        if intact > plan.first {
            // Frames before `intact` may be torn: drop them, count them as lost.
            let torn = (intact - plan.first).min(plan.frames as u64) as usize;
            for dst in out.iter_mut() {
                dst.copy_within(torn..plan.frames, 0);
            }
            outcome.frames -= torn;
            outcome.loss += torn as u64;
        }
        outcome
    }
}
