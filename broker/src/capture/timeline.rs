//! The capture's timeline: where the device's stream should be, and the frames an overrun
//! lost (zero-filled as GAP).

use super::{Assembler, CaptureParams};

/// Where the device's stream should be: the time of the frame after the last one read, for
/// finding the frames an overrun (reported, or seen as a jump of the timestamps) lost. A
/// resumed port's timeline goes on from its last frame, the restart counted like an overrun.
pub(super) struct Timeline {
    expected_ns: Option<u64>,
    pub(super) after_xrun: bool,
    /// Timestamps further ahead than this of where the stream should be mean lost frames.
    unreported_gap_ns: u64,
    resumed: bool,
}

impl Timeline {
    pub(super) fn new(p: &CaptureParams, asm: &Assembler) -> Self {
        Timeline {
            expected_ns: p.resume_from_ns,
            after_xrun: p.resume_from_ns.is_some(),
            unreported_gap_ns: (4 * asm.frames_ns(asm.nfpc as u64)).max(100_000_000),
            resumed: p.resume_from_ns.is_some(),
        }
    }

    /// Before `frames` frames stamped `first_mono_ns` are assembled: zero-fills what was lost
    /// since the last ones (after a reported overrun, or when the timestamps jump ahead by more
    /// than the device's timing noise: a device path that drops frames without reporting it,
    /// such as ALSA's jack plugin when the broker froze).
    pub(super) fn before_frames(&mut self, asm: &mut Assembler, first_mono_ns: u64, frames: usize) {
        let jump = self.expected_ns.map_or(0, |exp| first_mono_ns.saturating_sub(exp));
        if !self.after_xrun && jump > self.unreported_gap_ns {
            asm.shared.writer().add_xruns(1);
            tracing::warn!(
                jump_ms = jump / 1_000_000,
                "device timestamps jumped ahead: frames were lost unreported"
            );
            self.after_xrun = true;
        }
        if self.after_xrun {
            self.after_xrun = false;
            asm.discontinuity = true;
            if let Some(exp) = self.expected_ns {
                let gap = ((jump as f64) * asm.rate as f64 / 1e9).round() as u64;
                if asm.published == 0 && self.resumed {
                    tracing::info!(
                        gap_frames = gap,
                        gap_ms = jump / 1_000_000,
                        "resumed after a restart; the frames missed meanwhile are published as GAP"
                    );
                } else {
                    tracing::warn!(gap_frames = gap, "overrun recovered; zero-filling the lost frames");
                }
                asm.push_zeros(gap, exp);
            }
        }
        self.expected_ns = Some(first_mono_ns + asm.frames_ns(frames as u64));
    }
}
