//! Unit tests of the ring's word copies: every alignment and length, and never a read past
//! the sample words.

use super::*;

/// Every run start (both word halves, every 16-byte alignment of the source), every
/// destination alignment and every length around the wide copy's blocks reads exactly
/// the stored samples, and writes nothing outside its destination.
#[test]
fn copy_reads_every_alignment_and_length() {
    let all: Vec<AtomicU64> = (0..201u64).map(|_| AtomicU64::new(0)).collect();
    // Both alignments of the word array itself (a port's is page aligned).
    for skip in 0..2 {
        let words = &all[skip..skip + 200];
        store_run(words, 0, 400, |i| (i as i32) * 7 - 1000);
        let mut buf = vec![0i32; 200];
        for g0 in (0..8).chain(390..400) {
            for off in 0..4 {
                for len in 0..=(400 - g0).min(150) {
                    buf.fill(i32::MIN);
                    load_run(words, g0, &mut buf[1 + off..1 + off + len]);
                    for (i, v) in buf.iter().enumerate() {
                        let expect = if (1 + off..1 + off + len).contains(&i) {
                            ((g0 + i - 1 - off) as i32) * 7 - 1000
                        } else {
                            i32::MIN
                        };
                        assert_eq!(
                            *v, expect,
                            "buffer[{i}]: skip {skip}, g0 {g0}, dst offset {off}, len {len}"
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
    let n = 200;
    // SAFETY: the last `8 n` bytes of the readable first page, zeroed by mmap, 8-byte
    // aligned; AtomicU64 has the layout of u64 and any bit pattern is valid.
    let words: &[AtomicU64] = unsafe { std::slice::from_raw_parts(base.add(PAGE - 8 * n).cast(), n) };
    store_run(words, 0, 2 * n, |i| i as i32 + 1);
    let mut buf = vec![0i32; 2 * n + 4];
    for len in 0..=2 * n {
        for off in 0..4 {
            let dst = &mut buf[off..off + len];
            load_run(words, 2 * n - len, dst);
            assert!(
                dst.iter().enumerate().all(|(i, v)| *v == (2 * n - len + i) as i32 + 1),
                "len {len}, offset {off}"
            );
        }
    }
    // SAFETY: the page protected above, made accessible again before the mapping goes.
    let rc = unsafe { libc::mprotect(base.add(PAGE).cast(), PAGE, libc::PROT_READ | libc::PROT_WRITE) };
    assert_eq!(rc, 0, "mprotect");
    drop(map);
}
