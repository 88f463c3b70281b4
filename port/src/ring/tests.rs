//! Unit tests of the ring's word copies (every alignment and length, and never a read past
//! the sample words) and of its slot arithmetic.

use super::*;

/// Every copy path this machine has: every run start (both word halves, every 16- and 32-byte
/// alignment of the source), every destination alignment (mod 32 bytes) and every length around
/// the wide copies' blocks, the AVX2 threshold and the `rep movsb` threshold reads exactly the
/// stored samples, and writes nothing outside its destination.
#[test]
fn copy_reads_every_alignment_and_length() {
    let paths = paths_here();
    assert!(paths.contains(&CopyPath::Portable));
    let all: Vec<AtomicU64> = (0..1201u64).map(|_| AtomicU64::new(0)).collect();
    // Lengths around the 16-byte loop's blocks, the 32-byte loop's threshold (128 samples) and
    // blocks, around 2 KiB (512 samples), and a long one.
    let lens: Vec<usize> = (0..=200).chain(505..=520).chain([1100]).collect();
    for (path, skip) in paths.into_iter().flat_map(|p| [(p, 0), (p, 1)]) {
        // Both alignments of the word array itself (a port's is page aligned).
        let words = &all[skip..skip + 1200];
        store_run(words, 0, 2400, |i| (i as i32) * 7 - 1000);
        let mut buf = vec![0i32; 1110];
        for g0 in (0..8).chain(1290..1300).chain(2390..2400) {
            for off in 0..8 {
                for &len in lens.iter().filter(|&&l| l <= 2400 - g0) {
                    buf.fill(i32::MIN);
                    load_run_by(path, words, g0, &mut buf[1 + off..1 + off + len]);
                    for (i, v) in buf.iter().enumerate() {
                        let expect = if (1 + off..1 + off + len).contains(&i) {
                            ((g0 + i - 1 - off) as i32) * 7 - 1000
                        } else {
                            i32::MIN
                        };
                        assert_eq!(
                            *v, expect,
                            "buffer[{i}]: {path:?}, skip {skip}, g0 {g0}, dst offset {off}, len {len}"
                        );
                    }
                }
            }
        }
    }
}

/// A run ending at the very end of the sample words (the wide copy's last vectors) reads
/// nothing past them: the words end at a page followed by an inaccessible one.
#[test]
fn copy_never_reads_past_the_words() {
    const PAGE: usize = 4096;
    let mut map = memmap2::MmapMut::map_anon(2 * PAGE).expect("mmap");
    let base = map.as_mut_ptr();
    // SAFETY: the second page of the mapping made above, which nothing references.
    let rc = unsafe { libc::mprotect(base.add(PAGE).cast(), PAGE, libc::PROT_NONE) };
    assert_eq!(rc, 0, "mprotect");
    let n = 400;
    // SAFETY: the last `8 n` bytes of the readable first page, zeroed by mmap, 8-byte
    // aligned; AtomicU64 has the layout of u64 and any bit pattern is valid.
    let words: &[AtomicU64] = unsafe { std::slice::from_raw_parts(base.add(PAGE - 8 * n).cast(), n) };
    store_run(words, 0, 2 * n, |i| i as i32 + 1);
    let mut buf = vec![0i32; 2 * n + 8];
    for path in paths_here() {
        for len in 0..=2 * n {
            for off in 0..8 {
                let dst = &mut buf[off..off + len];
                load_run_by(path, words, 2 * n - len, dst);
                assert!(
                    dst.iter().enumerate().all(|(i, v)| *v == (2 * n - len + i) as i32 + 1),
                    "{path:?}: len {len}, offset {off}"
                );
            }
        }
    }
    // SAFETY: the page protected above, made accessible again before the mapping goes.
    let rc = unsafe { libc::mprotect(base.add(PAGE).cast(), PAGE, libc::PROT_READ | libc::PROT_WRITE) };
    assert_eq!(rc, 0, "mprotect");
    drop(map);
}

/// The slot of a frame is `(frame mod nFOP + nFOP - 1) mod nFOP` (frame 0 in the last slot) for
/// every window size and at the ends of the frame range, computed with one division.
#[test]
fn slot_is_the_frame_one_back_modulo_the_window() {
    for n in [1u64, 2, 3, 7, 441, 441_441, (1 << 32) + 1, u64::MAX / 2] {
        let frames = (0..3 * n.min(50)).chain([n - 1, n, n + 1, 2 * n, u64::MAX - 1, u64::MAX]);
        for f in frames {
            let expect = ((f % n) as u128 + n as u128 - 1) % n as u128;
            assert_eq!(slot(f, n) as u128, expect, "frame {f}, nFOP {n}");
        }
    }
}
