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
//! A replica window started at frame `F` ([`Ring::start_at`]) holds an intent floor of
//! `F - 1 + nFOP` until the window has passed `F`: by the same re-check, frames before `F`
//! (never written) count as lost, never as zero frames delivered.
//!
//! Samples are stored in 8-byte words, two samples per word, and every access to a
//! sample word, by the writer and by every reader, is a 64-bit Relaxed atomic of that same
//! aligned word: the sample area is one array of `AtomicU64`, never also accessed as 32-bit
//! atomics, so no mixed-size atomic access exists (which the memory model does not define).
//! The byte layout is unchanged from an `i32` array: sample `g` of the area (channel-planar,
//! `g = c * nFOP + slot`) occupies bytes `4g..4g + 4`, i.e. one half of word `g / 2`. A
//! write that covers only one half of a word (a run starting or ending at an odd sample)
//! loads the word, replaces its half and stores it whole: the writer is the only process
//! that stores, so the other half is written back with the value it already had. Readers
//! copy the aligned middle of a run a word at a time, which is what makes them fast (see
//! docs/port-format.md, "Copy width").
//!
//! This file only uses `crate::sync::atomic`, so the loom model in
//! `tests/loom_ring.rs` compiles it against loom's atomics unchanged.

use crate::sync::atomic::{fence, AtomicU64, Ordering};

/// The two samples of a word, in memory order.
#[inline(always)]
fn split(w: u64) -> [i32; 2] {
    let b = w.to_ne_bytes();
    [i32::from_ne_bytes([b[0], b[1], b[2], b[3]]), i32::from_ne_bytes([b[4], b[5], b[6], b[7]])]
}

/// The word holding samples `a` (lower address) and `b`.
#[inline(always)]
fn join(a: i32, b: i32) -> u64 {
    let (x, y) = (a.to_ne_bytes(), b.to_ne_bytes());
    u64::from_ne_bytes([x[0], x[1], x[2], x[3], y[0], y[1], y[2], y[3]])
}

/// Ring slot of frame `frame` in a window of `frames_on_port` frames.
///
/// Frame 0 (the zero frame before any data) maps to the last slot, which stays
/// zero until frame nFOP is written, when frame 0 has left the window.
/// Reduced first, so that any `frame` (a caller's nfr may be near 2^64) cannot overflow.
/// One division: `frame % nFOP + nFOP - 1` is below `2 nFOP`, so the second reduction is a
/// subtraction (a division costs 10–40 cycles, and every read computes a slot).
#[inline]
pub fn slot(frame: u64, frames_on_port: u64) -> u64 {
    let s = frame % frames_on_port + frames_on_port - 1;
    if s >= frames_on_port {
        s - frames_on_port
    } else {
        s
    }
}

/// Asks the CPU to fetch the cache line holding `*r`, which the caller is about to write
/// (x86-64: `prefetchw` where the build enables `prfchw`, `prefetcht0` on the baseline
/// target; a no-op on other targets, under loom and under Miri). Only a hint: it reads and
/// writes no memory, so it changes nothing any reader can see.
#[inline(always)]
pub fn prefetch_write<T>(r: &T) {
    #[cfg(all(target_arch = "x86_64", not(loom), not(miri)))]
    // SAFETY: a prefetch cannot fault and accesses no memory; `r` is a valid reference anyway.
    unsafe {
        use core::arch::x86_64::{_mm_prefetch, _MM_HINT_ET0};
        _mm_prefetch::<_MM_HINT_ET0>((r as *const T).cast::<i8>());
    }
    #[cfg(not(all(target_arch = "x86_64", not(loom), not(miri))))]
    let _ = r;
}

/// Frames per channel whose sample lines [`Ring::prefetch_publish`] asks for (512 bytes, 8
/// lines): all of a small chunk, and no more of a long one, whose later lines the processor's
/// own prefetcher streams in (asking for all 2205 frames of a 2205-frame chunk made its publish
/// 11–15 % dearer, measured side by side).
pub const PREFETCH_FRAMES: usize = 128;

/// Number of words holding `samples` samples.
#[inline]
pub const fn words_for(samples: u64) -> u64 {
    samples.div_ceil(2)
}

/// Stores `len` samples at sample positions `g0..g0 + len` of `words`, sample `i` being
/// `get(i)` (writer only: the half-word edges are read back from the writer's own stores).
#[inline(always)]
fn store_run(words: &[AtomicU64], g0: usize, len: usize, get: impl Fn(usize) -> i32) {
    let mut i = 0;
    if g0 & 1 == 1 && len > 0 {
        let w = &words[g0 >> 1];
        let [keep, _] = split(w.load(Ordering::Relaxed));
        w.store(join(keep, get(0)), Ordering::Relaxed);
        i = 1;
    }
    while i + 1 < len {
        words[(g0 + i) >> 1].store(join(get(i), get(i + 1)), Ordering::Relaxed);
        i += 2;
    }
    if i < len {
        let w = &words[(g0 + i) >> 1];
        let [_, keep] = split(w.load(Ordering::Relaxed));
        w.store(join(get(i), keep), Ordering::Relaxed);
    }
}

/// How a reader copies samples out of the shared window ([`copy_path`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum CopyPath {
    /// One Relaxed `AtomicU64` load per word (every target; the loom model and Miri).
    Portable = 0,
    /// Aligned 16-byte SSE2 loads in inline assembly (x86-64).
    Sse2 = 1,
    /// `rep movsb` in inline assembly for runs of at least 2 KiB, the 16-byte loads below
    /// (x86-64 with fast strings, ERMS).
    RepMovsb = 2,
    /// Aligned 32-byte AVX2 loads in inline assembly (x86-64 with AVX2).
    Avx2 = 3,
}

impl CopyPath {
    /// Every path, in the order above.
    pub const ALL: [CopyPath; 4] = [CopyPath::Portable, CopyPath::Sse2, CopyPath::RepMovsb, CopyPath::Avx2];

    /// Its name (`portable`, `sse2`, `movsb`, `avx2`), as `$BASS_COPY_PATH` spells it.
    pub fn name(self) -> &'static str {
        match self {
            CopyPath::Portable => "portable",
            CopyPath::Sse2 => "sse2",
            CopyPath::RepMovsb => "movsb",
            CopyPath::Avx2 => "avx2",
        }
    }

    /// The path named `s`.
    pub fn parse(s: &str) -> Option<CopyPath> {
        CopyPath::ALL.into_iter().find(|p| p.name() == s)
    }
}

#[cfg(all(target_arch = "x86_64", not(loom), not(miri)))]
pub use wide::{copy_path, set_copy_path};

/// The copy path: the portable one on this target.
#[cfg(not(all(target_arch = "x86_64", not(loom), not(miri))))]
pub fn copy_path() -> CopyPath {
    CopyPath::Portable
}

/// Refuses every path but the portable one on this target.
#[cfg(not(all(target_arch = "x86_64", not(loom), not(miri))))]
pub fn set_copy_path(p: CopyPath) -> Result<(), String> {
    match p {
        CopyPath::Portable => Ok(()),
        _ => Err(format!("{}: this target copies with the portable path only", p.name())),
    }
}

/// Loads the samples at positions `g0..g0 + dst.len()` of `words` into `dst`.
///
/// On x86-64 the copy is made in inline assembly ([`wide::load_run`]): aligned 32-byte AVX2
/// loads, `rep movsb` for long runs, or aligned 16-byte SSE2 loads, with aligned stores (which
/// one per CPU: [`wide::copy_path`]). The compiler never vectorises atomic loads, and a loop
/// of `AtomicU64` loads (the portable path, [`load_run_portable`]) runs at about 0.5–0.6×
/// memcpy. The loom model and Miri run the portable path.
#[inline(always)]
fn load_run(words: &[AtomicU64], g0: usize, dst: &mut [i32]) {
    #[cfg(all(target_arch = "x86_64", not(loom), not(miri)))]
    wide::load_run(words, g0, dst);
    #[cfg(not(all(target_arch = "x86_64", not(loom), not(miri))))]
    load_run_portable(words, g0, dst);
}

/// [`load_run`] by path `p`, and the paths this machine has (the tests run every one).
#[cfg(all(test, not(loom)))]
fn load_run_by(p: CopyPath, words: &[AtomicU64], g0: usize, dst: &mut [i32]) {
    #[cfg(all(target_arch = "x86_64", not(miri)))]
    wide::load_run_with(p, words, g0, dst);
    #[cfg(not(all(target_arch = "x86_64", not(miri))))]
    {
        assert_eq!(p, CopyPath::Portable);
        load_run_portable(words, g0, dst);
    }
}

#[cfg(all(test, not(loom)))]
fn paths_here() -> Vec<CopyPath> {
    #[cfg(all(target_arch = "x86_64", not(miri)))]
    return CopyPath::ALL.into_iter().filter(|&p| wide::supported(p)).collect();
    #[cfg(not(all(target_arch = "x86_64", not(miri))))]
    return vec![CopyPath::Portable];
}

/// [`load_run`] with one Relaxed `AtomicU64` load per word.
#[inline(always)]
fn load_run_portable(words: &[AtomicU64], g0: usize, dst: &mut [i32]) {
    let len = dst.len();
    let mut i = 0;
    if g0 & 1 == 1 && len > 0 {
        dst[0] = split(words[g0 >> 1].load(Ordering::Relaxed))[1];
        i = 1;
    }
    let pairs = (len - i) / 2;
    let first = (g0 + i) >> 1;
    for (d, w) in dst[i..i + 2 * pairs].chunks_exact_mut(2).zip(&words[first..first + pairs]) {
        let [a, b] = split(w.load(Ordering::Relaxed));
        d[0] = a;
        d[1] = b;
    }
    i += 2 * pairs;
    if i < len {
        dst[i] = split(words[(g0 + i) >> 1].load(Ordering::Relaxed))[0];
    }
}

/// The wide copy of x86-64 (why it is sound: its module comment).
#[cfg(all(target_arch = "x86_64", not(loom), not(miri)))]
#[path = "ring/wide.rs"] // explicit: tests/loom_ring.rs includes this file by path
mod wide;

/// One channel's ring of nFOP samples inside the shared sample words.
#[derive(Clone, Copy)]
pub struct ChannelRing<'a> {
    words: &'a [AtomicU64],
    base: usize,
    len: usize,
}

impl<'a> ChannelRing<'a> {
    /// Samples in the ring (nFOP).
    #[inline]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the ring is empty (never, for a valid port).
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The sample in `slot` (a Relaxed load of its word). Panics if `slot >= len()`.
    #[inline]
    pub fn load(&self, slot: usize) -> i32 {
        assert!(slot < self.len, "slot {slot} outside a ring of {}", self.len);
        let g = self.base + slot;
        split(self.words[g >> 1].load(Ordering::Relaxed))[g & 1]
    }

    /// Copies the samples of slots `start..start + dst.len()`. Panics past the ring's end.
    #[inline]
    pub fn copy_to(&self, start: usize, dst: &mut [i32]) {
        assert!(start <= self.len && dst.len() <= self.len - start, "copy outside the ring");
        load_run(self.words, self.base + start, dst);
    }

    /// Address of slot 0, for zero-copy readers in C (the samples are an `i32` array in
    /// memory; C reads them in place and checks the view afterwards).
    #[inline]
    pub fn as_ptr(&self) -> *const i32 {
        // The words are 8-byte aligned and samples are 4 bytes: sample `base` starts at
        // byte 4 * base of the word array.
        (self.words.as_ptr() as *const i32).wrapping_add(self.base)
    }

    /// The word holding `slot` (for tests that probe the mapping's protection).
    pub fn word_of(&self, slot: usize) -> &'a AtomicU64 {
        assert!(slot < self.len, "slot {slot} outside a ring of {}", self.len);
        &self.words[(self.base + slot) >> 1]
    }
}

/// Views of the shared window's protocol words and samples.
pub struct Ring<'a> {
    /// Newest published frame.
    pub last_frame_index: &'a AtomicU64,
    /// Newest frame the writer may be writing.
    pub write_intent: &'a AtomicU64,
    /// Channel-planar rings, `channels * frames_on_port` samples, two per word
    /// ([`words_for`]).
    pub samples: &'a [AtomicU64],
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
    pub fn channel(&self, c: usize) -> ChannelRing<'a> {
        let n = self.frames_on_port as usize;
        assert!(
            words_for(((c + 1) * n) as u64) as usize <= self.samples.len(),
            "channel {c} outside the rings"
        );
        ChannelRing { words: self.samples, base: c * n, len: n }
    }

    /// Ring slot of `frame`.
    #[inline]
    fn slot(&self, frame: u64) -> usize {
        slot(frame, self.frames_on_port) as usize
    }

    /// Asks the CPU to fetch, for writing, the cache lines of the first samples of each channel
    /// that a publish of `count` frames after frame `lfi` stores: at most
    /// [`PREFETCH_FRAMES`] per channel (writer only; a hint, see [`prefetch_write`]). The writer
    /// issues it before it stores anything, so that the lines, usually cold after the writer
    /// slept, arrive together rather than one miss after another.
    #[inline]
    pub fn prefetch_publish(&self, lfi: u64, count: usize, channels: usize) {
        let n = self.frames_on_port as usize;
        let start = self.slot(lfi + 1);
        let len = count.min(n - start).min(PREFETCH_FRAMES);
        if len == 0 {
            return;
        }
        for c in 0..channels {
            let (first, last) = ((c * n + start) / 2, (c * n + start + len - 1) / 2);
            // A word every 64 bytes, and the last word (the run need not start on a line).
            for w in (first..=last).step_by(8).chain([last]) {
                if let Some(w) = self.samples.get(w) {
                    prefetch_write(w);
                }
            }
        }
    }

    /// Publishes `count` frames after frame `lfi`, the current last frame index (writer only,
    /// which owns that value and the intent; `count <= nFOP`). Returns the new last frame
    /// index.
    ///
    /// The intent announced is `max(new last frame, current intent)`: an intent above the last
    /// frame is a floor a replica writer set ([`Ring::start_at`]) to condemn the frames before
    /// its first one, and it stays until the window has passed them. In every other case the
    /// intent equals the last frame between publishes, so this is the new last frame.
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
        self.publish_impl(lfi, count, channels, src, under_intent, true)
    }

    /// The known-bad variant for the loom model: announces the new last frame as the intent,
    /// lowering a start's floor (frames before a replica's start then read as zeros).
    #[cfg(loom)]
    pub fn publish_without_floor(&self, lfi: u64, count: usize, channels: usize, src: &Source<'_>) -> u64 {
        self.publish_impl(lfi, count, channels, src, || {}, false)
    }

    #[inline(always)]
    fn publish_impl(
        &self,
        lfi: u64,
        count: usize,
        channels: usize,
        src: &Source<'_>,
        under_intent: impl FnOnce(),
        keep_floor: bool,
    ) -> u64 {
        let new_lfi = lfi + count as u64;
        // Announce the frames about to be overwritten before touching any sample (never
        // lowering a floor: Relaxed suffices to read back what only this writer stores).
        let floor = if keep_floor { self.write_intent.load(Ordering::Relaxed) } else { 0 };
        self.write_intent.store(new_lfi.max(floor), Ordering::Relaxed);
        fence(Ordering::Release);
        under_intent();
        let mut done = 0usize;
        while done < count {
            let start = self.slot(lfi + 1 + done as u64);
            let len = (count - done).min(self.frames_on_port as usize - start);
            for c in 0..channels {
                let g0 = self.channel(c).base + start;
                match src {
                    Source::Interleaved(s) => {
                        store_run(self.samples, g0, len, |i| s[(done + i) * channels + c]);
                    }
                    Source::Planar(p) => {
                        let p = &p[c][done..done + len];
                        store_run(self.samples, g0, len, |i| p[i]);
                    }
                    Source::Zeros => store_run(self.samples, g0, len, |_| 0),
                }
            }
            done += len;
        }
        self.last_frame_index.store(new_lfi, Ordering::Release);
        new_lfi
    }

    /// Starts an empty window (`last_frame_index == 0`, writer only) at frame `first`: the next
    /// publish writes frame `first`, and frames `1..first` — never written — count as lost for
    /// every reader rather than reading as zeros. The intent is set to `first - 1 + nFOP`, so
    /// [`Ring::first_intact`] is `first` until the window has passed it; [`Ring::publish`]
    /// keeps that floor. `first >= 1`, and `first - 1 + nFOP` must not overflow.
    ///
    /// No frame is published yet, so no reader can have copied anything: the intent is moved
    /// before the last frame index, keeping `intent >= last_frame_index` at every step.
    pub fn start_at(&self, first: u64) {
        debug_assert!(first >= 1);
        self.write_intent.store(first - 1 + self.frames_on_port, Ordering::Relaxed);
        self.last_frame_index.store(first - 1, Ordering::Release);
    }

    /// Moves the window of a writer whose last frame is `lfi` on to frame `first` without
    /// writing anything (writer only): frames `lfi + 1 .. first`, never written, and every
    /// frame before them still in the window count as lost for every reader, and the next
    /// publish writes frame `last + 1`, where `last` (returned) is the frame before the chunk
    /// boundary at or below `first` (`chunk` frames per chunk). Requires `lfi < first`.
    ///
    /// The intent floor `first - 1 + nFOP` is announced before the last frame index moves,
    /// so a reader that sees the new last frame also sees every frame below `first` condemned,
    /// and one still copying the old window finds what it copied condemned on its re-check.
    pub fn skip_to(&self, lfi: u64, first: u64, chunk: u64) -> u64 {
        debug_assert!(first > lfi && chunk > 0);
        let last = (first - 1) / chunk * chunk;
        let floor = (first - 1 + self.frames_on_port).max(self.write_intent.load(Ordering::Relaxed));
        self.write_intent.store(floor, Ordering::Relaxed);
        fence(Ordering::Release);
        let last = last.max(lfi);
        self.last_frame_index.store(last, Ordering::Release);
        last
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
            ring.copy_to(start, &mut dst[done..done + len]);
            done += len;
        }
    }

    /// The ring segments (start slot, length) of the `frames <= nFOP` frames from `first`: the
    /// second is empty unless the run wraps around the ring's end.
    #[inline]
    fn segments(&self, first: u64, frames: usize) -> [(usize, usize); 2] {
        let start = self.slot(first);
        let len0 = frames.min(self.frames_on_port as usize - start);
        [(start, len0), (0, frames - len0)]
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
        // A plan never exceeds the window, so its frames are at most two segments, the same
        // in every channel (one slot computation per read, not per channel).
        let [(s0, l0), (s1, l1)] = self.segments(plan.first, plan.frames);
        for (c, dst) in out.iter_mut().enumerate() {
            let ring = self.channel(c);
            ring.copy_to(s0, &mut dst[..l0]);
            if l1 > 0 {
                ring.copy_to(s1, &mut dst[l0..l0 + l1]);
            }
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
            if intact > end {
                // Every frame copied was condemned, and the ones after them up to `intact`
                // too (a writer that skipped ahead, see `skip_to`): the whole run is one loss,
                // reported at once rather than `max` frames per call.
                outcome.loss += intact - end;
                outcome.next_frame = intact;
            }
        }
        outcome
    }
}

#[cfg(all(test, not(loom)))]
#[path = "ring/tests.rs"] // explicit: tests/loom_ring.rs includes this file by path
mod tests;
