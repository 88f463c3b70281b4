//! The wide copy of x86-64: aligned 32-byte AVX2 loads, aligned 16-byte SSE2 loads, or
//! `rep movsb` for long runs on a CPU with fast strings (ERMS), the instruction glibc's memcpy
//! uses for large copies. Which one a CPU gets by default is the one measured best on it
//! ([`copy_path`]; docs/performance.md, part 1).
//!
//! Why the 16-byte loads are sound (the argument of docs/port-format.md, "Copy width"): every load is an
//! aligned 16-byte `movdqa` of the sample area, made in inline assembly, so the compiler
//! sees no plain read of memory another process writes (the assembly is opaque to it, like
//! an atomic operation). Each such load reads two whole aligned 8-byte sample words, the unit
//! the writer stores atomically; the processor performs it atomically on every processor with
//! AVX and as aligned quadword reads on the others, so it stands for two Relaxed `AtomicU64`
//! loads of the same width as the writer's stores. Loads may cover words next to the run
//! (the aligned vectors around its ends, inside `words`); their values are not used. The
//! protocol around the copy (Acquire load of the last frame, `fence(Acquire)` and the
//! intent re-check after it) is unchanged: the assembly is not `nomem`, so the compiler
//! keeps it before the fence.
//!
//! Why the 32-byte loads are sound: the same argument, for an aligned 32-byte `vmovdqa` (VEX.256)
//! in inline assembly. Each reads four whole aligned 8-byte sample words and nothing else: a
//! 32-byte aligned vector never straddles a sample word (words are 8-byte aligned) nor a cache
//! line. The architecture promises no atomicity for the whole 32 bytes, and none is needed: the
//! processor may split the load, but only into naturally aligned pieces of at least a quadword
//! (aligned quadword or wider reads: the width at which aligned accesses are atomic, Intel SDM
//! vol. 3A, "Guaranteed atomic operations"; AMD APM vol. 2, "Access atomicity"), so each sample
//! word is read whole, like a Relaxed `AtomicU64` load. Even a processor that read a word in
//! pieces could only tear a word the writer stores into during the copy, which belongs to a
//! frame the intent re-check drops: the `rep movsb` argument below. The upper halves of the
//! vector registers are cleared (`vzeroupper`, inserted by the compiler on leaving the
//! AVX2 functions), so SSE code after the copy pays no transition penalty.
//!
//! Why `rep movsb` is sound: it is inline assembly too, so the compiler sees no plain read of
//! the shared words and can neither split, merge, repeat nor elide it; it reads exactly the
//! run's bytes. A fast-string copy is atomic at no particular width, so a sample the writer
//! stores into during the copy may be read torn: such a sample belongs to a frame the intent
//! re-check after the copy drops (the writer announces every slot it may write before writing
//! it), so a torn value never reaches the caller. This is the model of a seqlock read with a
//! per-byte atomic copy (Rust RFC 3301, `AtomicPerByte`), which x86's memory model defines:
//! a load racing a store returns, byte for byte, the old or the new value.

use super::{load_run_portable, CopyPath};
use std::arch::x86_64::{
    __m128i, __m256i, _mm256_alignr_epi8, _mm256_permute2x128_si256, _mm256_store_si256, _mm_or_si128,
    _mm_slli_si128, _mm_srli_si128, _mm_store_si128,
};
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};

/// Shortest run (bytes) copied by `rep movsb` on the `RepMovsb` path: below it the start-up
/// of a string instruction costs more than the 16-byte loop (docs/performance.md, part 1).
pub const MOVSB_MIN_BYTES: usize = 2048;

/// The path in use (`CopyPath as u8`), or `UNCHOSEN` before the first copy.
static PATH: AtomicU8 = AtomicU8::new(UNCHOSEN);
const UNCHOSEN: u8 = u8::MAX;

/// Whether this CPU has fast strings (ERMS: `rep movsb` moves whole cache lines).
fn has_erms() -> bool {
    std::arch::is_x86_feature_detected!("ermsb")
}

/// Whether this CPU has AVX2 (32-byte integer vectors).
fn has_avx2() -> bool {
    std::arch::is_x86_feature_detected!("avx2")
}

/// Whether this CPU is an AMD (or Hygon, AMD's Zen licensee) processor.
fn is_amd() -> bool {
    // SAFETY: `cpuid` leaf 0 exists on every x86-64 processor; it only writes registers.
    // (A safe function on newer toolchains, an unsafe one on older: hence the allow.)
    #[allow(unused_unsafe)]
    let id = unsafe { std::arch::x86_64::__cpuid(0) };
    let mut vendor = [0u8; 12];
    vendor[..4].copy_from_slice(&id.ebx.to_le_bytes());
    vendor[4..8].copy_from_slice(&id.edx.to_le_bytes());
    vendor[8..].copy_from_slice(&id.ecx.to_le_bytes());
    &vendor == b"AuthenticAMD" || &vendor == b"HygonGenuine"
}

/// The path measured best on this kind of CPU (docs/performance.md, part 1):
/// - AMD with AVX2: `avx2`. Its fast-string `rep movsb` slows to a fraction of its speed when
///   source and destination are close modulo 4 KiB (10-12 GB/s against 35-40 for the AVX2
///   loop on a Zen 3 EPYC; glibc stopped using it on Zen 3/4 for that, its bug 30994), and a
///   reader's buffers can sit at any distance from the window.
/// - Other CPUs with ERMS (Intel): `movsb` (0.98x memcpy hot at 64 KiB against 0.95x for
///   `sse2`, equal streaming, on a Xeon).
/// - Other CPUs with AVX2: `avx2`; the rest `sse2`.
fn default_path() -> CopyPath {
    match (has_avx2(), has_erms()) {
        (true, _) if is_amd() => CopyPath::Avx2,
        (_, true) => CopyPath::RepMovsb,
        (true, false) => CopyPath::Avx2,
        (false, false) => CopyPath::Sse2,
    }
}

/// The copy path: the one set by [`set_copy_path`], else `$BASS_COPY_PATH` (`sse2`, `movsb`,
/// `avx2`, `portable`; anything else, or a path this CPU lacks, is ignored), else the one
/// measured best on this kind of CPU (`avx2` on AMD, `movsb` on Intel: [`default_path`]).
/// Chosen once per process.
#[inline]
pub fn copy_path() -> CopyPath {
    match PATH.load(Ordering::Relaxed) {
        0 => CopyPath::Portable,
        1 => CopyPath::Sse2,
        2 => CopyPath::RepMovsb,
        3 => CopyPath::Avx2,
        _ => choose_path(),
    }
}

/// The first call of [`copy_path`]: chooses the path and keeps it.
#[cold]
fn choose_path() -> CopyPath {
    let wanted = std::env::var("BASS_COPY_PATH").ok().and_then(|v| CopyPath::parse(&v));
    let p = match wanted {
        Some(p) if supported(p) => p,
        _ => default_path(),
    };
    // A racing first call stores the same choice.
    PATH.store(p as u8, Ordering::Relaxed);
    p
}

/// Whether this CPU can run path `p`.
pub(super) fn supported(p: CopyPath) -> bool {
    match p {
        CopyPath::RepMovsb => has_erms(),
        CopyPath::Avx2 => has_avx2(),
        CopyPath::Portable | CopyPath::Sse2 => true,
    }
}

/// Makes every later copy of this process use `p` (the bench compares the paths); refuses a
/// path this CPU lacks.
pub fn set_copy_path(p: CopyPath) -> Result<(), String> {
    if !supported(p) {
        let lacks = if p == CopyPath::Avx2 { "AVX2" } else { "fast strings (ERMS)" };
        return Err(format!("{}: this CPU has no {lacks}", p.name()));
    }
    PATH.store(p as u8, Ordering::Relaxed);
    Ok(())
}

/// Copies `n` bytes from `src` to `dst` with `rep movsb`.
///
/// # Safety
/// `src .. src + n` lies inside one live `[AtomicU64]`; `dst .. dst + n` lies inside memory
/// the caller borrows exclusively; the two do not overlap.
#[inline(always)]
unsafe fn movsb(src: *const u8, dst: *mut u8, n: usize) {
    // SAFETY: the caller guarantees both ranges; the instruction reads exactly
    // `src .. src + n` and writes exactly `dst .. dst + n` (the direction flag is clear, as
    // the ABI requires at every call), uses no stack and leaves the flags alone. See the
    // module's comment for why the racing read of the shared words is sound.
    unsafe {
        std::arch::asm!(
            "rep movsb",
            inout("rcx") n => _,
            inout("rsi") src => _,
            inout("rdi") dst => _,
            options(nostack, preserves_flags),
        );
    }
}

/// Output vectors per assembly block (4 × 16 bytes).
const BLOCK: usize = 4;

/// Four aligned 16-byte loads from `p .. p + 64`.
///
/// # Safety
/// `p` is 16-byte aligned and `p .. p + 64` lies inside one live `[AtomicU64]`.
#[inline(always)]
unsafe fn load4(p: *const u8) -> [__m128i; 4] {
    let (v0, v1, v2, v3): (__m128i, __m128i, __m128i, __m128i);
    // SAFETY: the caller guarantees alignment and bounds; the assembly only reads those
    // 64 bytes (`readonly`, `nostack`), as four aligned loads of whole sample words (see
    // the module's comment for why that is the writer's access width).
    unsafe {
        std::arch::asm!(
            "movdqa {v0}, [{p}]",
            "movdqa {v1}, [{p} + 16]",
            "movdqa {v2}, [{p} + 32]",
            "movdqa {v3}, [{p} + 48]",
            p = in(reg) p,
            v0 = out(xmm_reg) v0,
            v1 = out(xmm_reg) v1,
            v2 = out(xmm_reg) v2,
            v3 = out(xmm_reg) v3,
            options(nostack, readonly, preserves_flags),
        );
    }
    [v0, v1, v2, v3]
}

/// One aligned 16-byte load from `p`.
///
/// # Safety
/// As [`load4`], for `p .. p + 16`.
#[inline(always)]
unsafe fn load1(p: *const u8) -> __m128i {
    let v: __m128i;
    // SAFETY: as in `load4`, for 16 bytes.
    unsafe {
        std::arch::asm!("movdqa {v}, [{p}]", p = in(reg) p, v = out(xmm_reg) v,
            options(nostack, readonly, preserves_flags));
    }
    v
}

/// Copies `vectors` 16-byte vectors from `src + T` (a 16-byte aligned `src`, `T` of 0,
/// 4, 8 or 12 bytes) to the 16-byte aligned `out`; each output vector is the bytes
/// `T .. T + 16` of two consecutive aligned source vectors.
///
/// # Safety
/// `src .. src + 16 * vectors` (plus 16 more bytes when `T > 0`) lies inside one live
/// `[AtomicU64]`; `out .. out + 16 * vectors` lies inside memory the caller borrows
/// exclusively; both are 16-byte aligned.
#[inline(always)]
unsafe fn copy_vectors<const T: i32>(src: *const u8, out: *mut __m128i, vectors: usize) {
    let blocks = vectors / BLOCK;
    // SAFETY: every load is inside the bounds the caller guarantees (the blocks read
    // `src .. src + 64 * blocks`, plus 16 with `T > 0` for the carried first vector; the
    // rest one vector at a time up to `16 * vectors`, plus 16), and every store writes
    // `out + k` for `k < vectors`.
    unsafe {
        if T == 0 {
            for b in 0..blocks {
                let v = load4(src.add(64 * b));
                for (k, x) in v.into_iter().enumerate() {
                    _mm_store_si128(out.add(BLOCK * b + k), x);
                }
            }
            for k in BLOCK * blocks..vectors {
                _mm_store_si128(out.add(k), load1(src.add(16 * k)));
            }
            return;
        }
        let join = |lo: __m128i, hi: __m128i| -> __m128i {
            // Bytes T..16 of `lo`, then bytes 0..T of `hi`.
            match T {
                4 => _mm_or_si128(_mm_srli_si128::<4>(lo), _mm_slli_si128::<12>(hi)),
                8 => _mm_or_si128(_mm_srli_si128::<8>(lo), _mm_slli_si128::<8>(hi)),
                _ => _mm_or_si128(_mm_srli_si128::<12>(lo), _mm_slli_si128::<4>(hi)),
            }
        };
        let mut prev = load1(src);
        for b in 0..blocks {
            let v = load4(src.add(16 + 64 * b));
            for (k, x) in v.into_iter().enumerate() {
                _mm_store_si128(out.add(BLOCK * b + k), join(prev, x));
                prev = x;
            }
        }
        for k in BLOCK * blocks..vectors {
            let x = load1(src.add(16 * (k + 1)));
            _mm_store_si128(out.add(k), join(prev, x));
            prev = x;
        }
    }
}

/// Four aligned 32-byte loads from `p .. p + 128`.
///
/// # Safety
/// The CPU has AVX2; `p` is 32-byte aligned and `p .. p + 128` lies inside one live
/// `[AtomicU64]`.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn load4_avx2(p: *const u8) -> [__m256i; 4] {
    let (v0, v1, v2, v3): (__m256i, __m256i, __m256i, __m256i);
    // SAFETY: the caller guarantees AVX2, alignment and bounds; the assembly only reads those
    // 128 bytes (`readonly`, `nostack`), as four aligned 32-byte loads, each of four whole
    // sample words (see the module's comment for why that is the writer's access width).
    unsafe {
        std::arch::asm!(
            "vmovdqa {v0}, [{p}]",
            "vmovdqa {v1}, [{p} + 32]",
            "vmovdqa {v2}, [{p} + 64]",
            "vmovdqa {v3}, [{p} + 96]",
            p = in(reg) p,
            v0 = out(ymm_reg) v0,
            v1 = out(ymm_reg) v1,
            v2 = out(ymm_reg) v2,
            v3 = out(ymm_reg) v3,
            options(nostack, readonly, preserves_flags),
        );
    }
    [v0, v1, v2, v3]
}

/// One aligned 32-byte load from `p`.
///
/// # Safety
/// As [`load4_avx2`], for `p .. p + 32`.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn load1_avx2(p: *const u8) -> __m256i {
    let v: __m256i;
    // SAFETY: as in `load4_avx2`, for 32 bytes.
    unsafe {
        std::arch::asm!("vmovdqa {v}, [{p}]", p = in(reg) p, v = out(ymm_reg) v,
            options(nostack, readonly, preserves_flags));
    }
    v
}

/// [`copy_vectors`] with 32-byte vectors: copies `vectors` of them from `src + T` (a 32-byte
/// aligned `src`, `T` a multiple of 4 below 32) to the 32-byte aligned `out`; each output
/// vector is the bytes `T .. T + 32` of two consecutive aligned source vectors.
///
/// # Safety
/// The CPU has AVX2; `src .. src + 32 * vectors` (plus 32 more bytes when `T > 0`) lies inside
/// one live `[AtomicU64]`; `out .. out + 32 * vectors` lies inside memory the caller borrows
/// exclusively; both are 32-byte aligned.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn copy_vectors_avx2<const T: i32>(src: *const u8, out: *mut __m256i, vectors: usize) {
    let blocks = vectors / BLOCK;
    // SAFETY: every load is inside the bounds the caller guarantees (the blocks read
    // `src .. src + 128 * blocks`, plus 32 with `T > 0` for the carried first vector; the
    // rest one vector at a time up to `32 * vectors`, plus 32), and every store writes
    // `out + k` for `k < vectors`; the caller guarantees AVX2.
    unsafe {
        if T == 0 {
            for b in 0..blocks {
                let v = load4_avx2(src.add(128 * b));
                for (k, x) in v.into_iter().enumerate() {
                    _mm256_store_si256(out.add(BLOCK * b + k), x);
                }
            }
            for k in BLOCK * blocks..vectors {
                _mm256_store_si256(out.add(k), load1_avx2(src.add(32 * k)));
            }
            return;
        }
        // Bytes T..32 of `lo`, then bytes 0..T of `hi`: `mid` is lo's upper and hi's lower
        // 16 bytes, and `alignr` shifts within each 16-byte lane.
        macro_rules! join {
            ($lo:expr, $hi:expr) => {{
                let (lo, hi) = ($lo, $hi);
                let mid = _mm256_permute2x128_si256::<0x21>(lo, hi);
                match T {
                    4 => _mm256_alignr_epi8::<4>(mid, lo),
                    8 => _mm256_alignr_epi8::<8>(mid, lo),
                    12 => _mm256_alignr_epi8::<12>(mid, lo),
                    16 => mid,
                    20 => _mm256_alignr_epi8::<4>(hi, mid),
                    24 => _mm256_alignr_epi8::<8>(hi, mid),
                    _ => _mm256_alignr_epi8::<12>(hi, mid),
                }
            }};
        }
        let mut prev = load1_avx2(src);
        for b in 0..blocks {
            let v = load4_avx2(src.add(32 + 128 * b));
            for (k, x) in v.into_iter().enumerate() {
                _mm256_store_si256(out.add(BLOCK * b + k), join!(prev, x));
                prev = x;
            }
        }
        for k in BLOCK * blocks..vectors {
            let x = load1_avx2(src.add(32 * (k + 1)));
            _mm256_store_si256(out.add(k), join!(prev, x));
            prev = x;
        }
    }
}

/// [`copy_vectors_avx2`] for the source offset `t` (a multiple of 4 below 32).
///
/// # Safety
/// As [`copy_vectors_avx2`] with `T = t`.
#[target_feature(enable = "avx2")]
unsafe fn copy_avx2(src: *const u8, out: *mut __m256i, vectors: usize, t: usize) {
    // SAFETY: the caller's guarantees, passed on unchanged.
    unsafe {
        match t {
            0 => copy_vectors_avx2::<0>(src, out, vectors),
            4 => copy_vectors_avx2::<4>(src, out, vectors),
            8 => copy_vectors_avx2::<8>(src, out, vectors),
            12 => copy_vectors_avx2::<12>(src, out, vectors),
            16 => copy_vectors_avx2::<16>(src, out, vectors),
            20 => copy_vectors_avx2::<20>(src, out, vectors),
            24 => copy_vectors_avx2::<24>(src, out, vectors),
            _ => copy_vectors_avx2::<28>(src, out, vectors),
        }
    }
}

/// Loads the samples at positions `g0..g0 + dst.len()` of `words` into `dst`: the
/// samples before the first vector-aligned destination address and after the last whole
/// vector by the portable path, the middle a vector at a time.
#[inline(always)]
pub(super) fn load_run(words: &[AtomicU64], g0: usize, dst: &mut [i32]) {
    load_run_with(copy_path(), words, g0, dst)
}

/// Shortest run (samples) copied with 32-byte vectors on the `Avx2` path (shorter ones take
/// the 16-byte loads): with it the run always holds two blocks after its aligned head.
const AVX2_MIN_SAMPLES: usize = 128;

/// [`load_run`] by path `path` (a path this CPU lacks copies with the 16-byte loads).
#[inline(always)]
pub(super) fn load_run_with(path: CopyPath, words: &[AtomicU64], g0: usize, dst: &mut [i32]) {
    let len = dst.len();
    let base = words.as_ptr() as usize;
    let end = base + 8 * words.len();
    // The vector width in bytes.
    let width: usize = match path {
        CopyPath::Portable => return load_run_portable(words, g0, dst),
        CopyPath::RepMovsb if 4 * len >= MOVSB_MIN_BYTES => {
            assert!(4 * (g0 + len) <= 8 * words.len(), "run outside the sample words");
            // SAFETY: samples `g0 .. g0 + len` are bytes `4 * g0 .. 4 * (g0 + len)` of
            // `words` (checked just above); `dst` holds `len` samples and is borrowed
            // exclusively, so it cannot overlap the shared words.
            unsafe { movsb((base + 4 * g0) as *const u8, dst.as_mut_ptr() as *mut u8, 4 * len) };
            return;
        }
        CopyPath::Avx2 if len >= AVX2_MIN_SAMPLES && has_avx2() => 32,
        _ => 16,
    };
    // Samples to copy first so that the stores are vector aligned (dst is 4-aligned).
    let mut head = ((width - (dst.as_ptr() as usize & (width - 1))) & (width - 1)) / 4;
    // The aligned source vector holding the first sample of the middle must not start
    // before `words` (it can, by up to `width - 8` bytes, as `words` is only 8-byte aligned).
    if (base + 4 * (g0 + head)) & !(width - 1) < base {
        head += width / 4;
    }
    if len < head + width / 4 * BLOCK * 2 {
        return load_run_portable(words, g0, dst);
    }
    let first = base + 4 * (g0 + head);
    let t = first & (width - 1);
    let src = first - t;
    // Whole vectors that fit the run and, with the one extra vector read when the
    // source is not aligned like the destination, the words.
    let extra = if t == 0 { 0 } else { width };
    let vectors = ((len - head) / (width / 4)).min((end - src - extra) / width);
    let mid = head + width / 4 * vectors;
    load_run_portable(words, g0, &mut dst[..head]);
    let out = dst[head..mid].as_mut_ptr();
    let src = src as *const u8;
    // SAFETY: `src` is `width`-byte aligned, inside `words` (checked above), and
    // `src .. src + width * vectors + extra` ends inside it (`vectors` is bounded by
    // `end`); `out` is `dst[head..mid]`, `width`-byte aligned by the choice of `head`, and
    // holds `width / 4 * vectors` samples = `width * vectors` bytes; a width of 32 was chosen
    // only on a CPU with AVX2 (checked above).
    unsafe {
        match (width, t) {
            (32, _) => copy_avx2(src, out.cast(), vectors, t),
            (_, 0) => copy_vectors::<0>(src, out.cast(), vectors),
            (_, 4) => copy_vectors::<4>(src, out.cast(), vectors),
            (_, 8) => copy_vectors::<8>(src, out.cast(), vectors),
            _ => copy_vectors::<12>(src, out.cast(), vectors),
        }
    }
    load_run_portable(words, g0 + mid, &mut dst[mid..]);
}
