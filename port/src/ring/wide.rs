//! The wide copy of x86-64: aligned 16-byte loads, or `rep movsb` for long runs on a CPU
//! with fast strings (ERMS), the instruction glibc's memcpy uses for large copies.
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
//! Why `rep movsb` is sound: it is inline assembly too, so the compiler sees no plain read of
//! the shared words and can neither split, merge, repeat nor elide it; it reads exactly the
//! run's bytes. A fast-string copy is atomic at no particular width, so a sample the writer
//! stores into during the copy may be read torn: such a sample belongs to a frame the intent
//! re-check after the copy drops (the writer announces every slot it may write before writing
//! it), so a torn value never reaches the caller. This is the model of a seqlock read with a
//! per-byte atomic copy (Rust RFC 3301, `AtomicPerByte`), which x86's memory model defines:
//! a load racing a store returns, byte for byte, the old or the new value.

use super::{load_run_portable, CopyPath};
use std::arch::x86_64::{__m128i, _mm_or_si128, _mm_slli_si128, _mm_srli_si128, _mm_store_si128};
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

/// The copy path: the one set by [`set_copy_path`], else `$BASS_COPY_PATH` (`sse2`, `movsb`,
/// `portable`; anything else, or a path this CPU lacks, is ignored), else `rep movsb` on a CPU
/// with ERMS and the 16-byte loads on the others. Chosen once per process.
pub fn copy_path() -> CopyPath {
    match PATH.load(Ordering::Relaxed) {
        0 => CopyPath::Portable,
        1 => CopyPath::Sse2,
        2 => CopyPath::RepMovsb,
        _ => {
            let wanted = std::env::var("BASS_COPY_PATH").ok().and_then(|v| CopyPath::parse(&v));
            let p = match wanted {
                Some(p) if supported(p) => p,
                _ if has_erms() => CopyPath::RepMovsb,
                _ => CopyPath::Sse2,
            };
            // A racing first call stores the same choice.
            PATH.store(p as u8, Ordering::Relaxed);
            p
        }
    }
}

/// Whether this CPU can run path `p`.
pub(super) fn supported(p: CopyPath) -> bool {
    p != CopyPath::RepMovsb || has_erms()
}

/// Makes every later copy of this process use `p` (the bench compares the paths); refuses a
/// path this CPU lacks.
pub fn set_copy_path(p: CopyPath) -> Result<(), String> {
    if !supported(p) {
        return Err(format!("{}: this CPU has no fast strings (ERMS)", p.name()));
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

/// Loads the samples at positions `g0..g0 + dst.len()` of `words` into `dst`: the
/// samples before the first 16-byte aligned destination address and after the last whole
/// vector by the portable path, the middle a vector at a time.
#[inline(always)]
pub(super) fn load_run(words: &[AtomicU64], g0: usize, dst: &mut [i32]) {
    load_run_with(copy_path(), words, g0, dst)
}

/// [`load_run`] by path `path` (a path this CPU has).
#[inline(always)]
pub(super) fn load_run_with(path: CopyPath, words: &[AtomicU64], g0: usize, dst: &mut [i32]) {
    let len = dst.len();
    let base = words.as_ptr() as usize;
    let end = base + 8 * words.len();
    match path {
        CopyPath::Portable => return load_run_portable(words, g0, dst),
        CopyPath::RepMovsb if 4 * len >= MOVSB_MIN_BYTES => {
            assert!(4 * (g0 + len) <= 8 * words.len(), "run outside the sample words");
            // SAFETY: samples `g0 .. g0 + len` are bytes `4 * g0 .. 4 * (g0 + len)` of
            // `words` (checked just above); `dst` holds `len` samples and is borrowed
            // exclusively, so it cannot overlap the shared words.
            unsafe { movsb((base + 4 * g0) as *const u8, dst.as_mut_ptr() as *mut u8, 4 * len) };
            return;
        }
        _ => {}
    }
    // Samples to copy first so that the stores are 16-byte aligned (dst is 4-aligned).
    let mut head = ((16 - (dst.as_ptr() as usize & 15)) & 15) / 4;
    // The aligned source vector holding the first sample of the middle must not start
    // before `words` (it can, by 8 bytes, if `words` is not 16-byte aligned).
    if (base + 4 * (g0 + head)) & !15 < base {
        head += 4;
    }
    if len < head + 4 * BLOCK * 2 {
        return load_run_portable(words, g0, dst);
    }
    let first = base + 4 * (g0 + head);
    let t = first & 15;
    let src = first - t;
    // Whole vectors that fit the run and, with the one extra vector read when the
    // source is not aligned like the destination, the words.
    let extra = if t == 0 { 0 } else { 16 };
    let vectors = ((len - head) / 4).min((end - src - extra) / 16);
    let mid = head + 4 * vectors;
    load_run_portable(words, g0, &mut dst[..head]);
    let out = dst[head..mid].as_mut_ptr() as *mut __m128i;
    let src = src as *const u8;
    // SAFETY: `src` is 16-byte aligned, inside `words` (checked above), and
    // `src .. src + 16 * vectors + extra` ends inside it (`vectors` is bounded by
    // `end`); `out` is `dst[head..mid]`, 16-byte aligned by the choice of `head`, and
    // holds `4 * vectors` samples = `16 * vectors` bytes.
    unsafe {
        match t {
            0 => copy_vectors::<0>(src, out, vectors),
            4 => copy_vectors::<4>(src, out, vectors),
            8 => copy_vectors::<8>(src, out, vectors),
            _ => copy_vectors::<12>(src, out, vectors),
        }
    }
    load_run_portable(words, g0 + mid, &mut dst[mid..]);
}
