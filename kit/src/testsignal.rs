//! Deterministic test signals shared by the simulated device, the tests and the benchmarks.
//!
//! The *pattern* signal makes every sample name its own frame and channel, so a reader can
//! check each delivered sample: `pattern_sample(f, c)` for frame `f >= 1`, and 0 for the
//! zero frame 0 that precedes every acquisition.

/// Sample of the pattern signal for frame `frame` (>= 1) and channel `channel` (< 64):
/// the low 26 bits of the frame index above the 6-bit channel number.
#[inline]
pub fn pattern_sample(frame: u64, channel: u32) -> i32 {
    ((((frame & 0x03FF_FFFF) as u32) << 6) | (channel & 63)) as i32
}

/// What a reader must find for frame `frame` of the pattern signal (0 for frame 0).
#[inline]
pub fn pattern_expected(frame: u64, channel: u32) -> i32 {
    if frame == 0 {
        0
    } else {
        pattern_sample(frame, channel)
    }
}

/// Fills `out` (interleaved, `channels` per frame) with the pattern from frame `first`.
pub fn fill_pattern_interleaved(out: &mut [i32], channels: u32, first: u64) {
    for (i, frame) in out.chunks_exact_mut(channels as usize).enumerate() {
        for (c, s) in frame.iter_mut().enumerate() {
            *s = pattern_sample(first + i as u64, c as u32);
        }
    }
}
