//! A faithful model of the original BASS port (the seed's "Output port" section).
//!
//! Two arrays of nFOP samples (left, right) in shared memory, shifted as a FIFO: for every
//! chunk the writer memmoves the whole window by nFPC samples and copies the new chunk to
//! the end, then bumps `lastFrameIndex`. A client reads the port as the middleware does:
//! it copies the *whole* port structure (both arrays) into its own memory, then runs the
//! formal `getAudioData` on that copy. A process-shared reader-writer lock stands for the
//! middleware's port lock, so readers never see a half-shifted array.
//!
//! ```text
//!  0     rwlock (pthread_rwlock_t, process-shared)
//!  64    lastFrameIndex u64      72 futex u32 (bumped + woken per chunk)   76 stop u32
//!  80    nFPC u32  84 nCOP u32
//!  4096  left[nFOP] i32, right[nFOP] i32
//! ```

use std::path::Path;
use std::sync::atomic::Ordering::{Acquire, Relaxed, Release};

use bassport::sys::futex_wake_all;

use crate::shm::Region;

const OFF_LFI: usize = 64;
const OFF_FUTEX: usize = 72;
const OFF_STOP: usize = 76;
const OFF_NFPC: usize = 80;
const OFF_NCOP: usize = 84;
const OFF_DATA: usize = 4096;

/// One original-design port (writer or reader side).
pub struct OrigPort {
    region: Region,
    nfpc: usize,
    nfop: usize,
}

fn size_for(nfop: usize) -> usize {
    OFF_DATA + 2 * nfop * 4
}

impl OrigPort {
    /// Creates the port file, initialises the lock, touches the whole window (as a port
    /// that has been running for a while) and marks it full.
    pub fn create(path: &Path, nfpc: usize, ncop: usize) -> OrigPort {
        let nfop = nfpc * ncop;
        let region = Region::create(path, size_for(nfop));
        let lock = region.ptr() as *mut libc::pthread_rwlock_t;
        // SAFETY: `lock` points to zeroed, writable, suitably aligned shared memory of at
        // least size_of::<pthread_rwlock_t>() (< 64) bytes; attr is initialised before use
        // and destroyed after.
        unsafe {
            let mut attr: libc::pthread_rwlockattr_t = std::mem::zeroed();
            libc::pthread_rwlockattr_init(&mut attr);
            libc::pthread_rwlockattr_setpshared(&mut attr, libc::PTHREAD_PROCESS_SHARED);
            assert_eq!(libc::pthread_rwlock_init(lock, &attr), 0);
            libc::pthread_rwlockattr_destroy(&mut attr);
        }
        region.u32_at(OFF_NFPC).store(nfpc as u32, Relaxed);
        region.u32_at(OFF_NCOP).store(ncop as u32, Relaxed);
        let p = OrigPort { region, nfpc, nfop };
        let data = p.data();
        for i in 0..2 * nfop {
            // SAFETY: i < 2*nFOP, inside the data area; no reader exists yet.
            unsafe { *data.add(i) = (i as i32).wrapping_mul(7919) };
        }
        p.region.u64_at(OFF_LFI).store(nfop as u64, Release);
        p
    }

    /// Opens an existing port file.
    pub fn open(path: &Path) -> OrigPort {
        let hdr = Region::open(path, OFF_DATA);
        let nfpc = hdr.u32_at(OFF_NFPC).load(Relaxed) as usize;
        let ncop = hdr.u32_at(OFF_NCOP).load(Relaxed) as usize;
        drop(hdr);
        let nfop = nfpc * ncop;
        OrigPort { region: Region::open(path, size_for(nfop)), nfpc, nfop }
    }

    /// nFOP.
    pub fn nfop(&self) -> usize {
        self.nfop
    }

    fn lock(&self) -> *mut libc::pthread_rwlock_t {
        self.region.ptr() as *mut libc::pthread_rwlock_t
    }

    fn data(&self) -> *mut i32 {
        // SAFETY: OFF_DATA is inside the mapping (size_for(nfop) > OFF_DATA).
        unsafe { self.region.ptr().add(OFF_DATA) as *mut i32 }
    }

    /// The futex word bumped on every chunk.
    pub fn futex(&self) -> &std::sync::atomic::AtomicU32 {
        self.region.u32_at(OFF_FUTEX)
    }

    /// Whether the writer said stop.
    pub fn stopped(&self) -> bool {
        self.region.u32_at(OFF_STOP).load(Acquire) != 0
    }

    /// Tells readers to finish.
    pub fn stop(&self) {
        self.region.u32_at(OFF_STOP).store(1, Release);
        self.futex().fetch_add(1, Release);
        futex_wake_all(self.futex());
    }

    /// Publishes one interleaved stereo chunk the original way: shift the whole window.
    pub fn publish(&self, chunk: &[i32]) -> u64 {
        assert_eq!(chunk.len(), 2 * self.nfpc);
        let (n, k) = (self.nfop, self.nfpc);
        // SAFETY: the lock was initialised in `create`; the write lock excludes every reader,
        // so the plain memory accesses below race with nothing. All pointers stay inside the
        // two arrays: memmove of n - k samples from offset k to 0 in each, then k samples
        // written at n - k.
        unsafe {
            libc::pthread_rwlock_wrlock(self.lock());
            for c in 0..2 {
                let arr = self.data().add(c * n);
                std::ptr::copy(arr.add(k), arr, n - k);
                let tail = arr.add(n - k);
                for i in 0..k {
                    *tail.add(i) = chunk[2 * i + c];
                }
            }
            let lfi = self.region.u64_at(OFF_LFI).load(Relaxed) + k as u64;
            self.region.u64_at(OFF_LFI).store(lfi, Release);
            libc::pthread_rwlock_unlock(self.lock());
            self.futex().fetch_add(1, Release);
            futex_wake_all(self.futex());
            lfi
        }
    }

    /// Reads the port as a middleware client does: copies the whole port into `copy`
    /// (2 * nFOP samples) under the read lock. Returns the copy's lastFrameIndex.
    pub fn read_whole(&self, copy: &mut [i32]) -> u64 {
        assert_eq!(copy.len(), 2 * self.nfop);
        // SAFETY: the read lock excludes the writer, so the plain copy races with nothing;
        // source and destination are 2*nFOP samples, inside the mapping and `copy`.
        unsafe {
            libc::pthread_rwlock_rdlock(self.lock());
            let lfi = self.region.u64_at(OFF_LFI).load(Relaxed);
            std::ptr::copy_nonoverlapping(self.data(), copy.as_mut_ptr(), 2 * self.nfop);
            libc::pthread_rwlock_unlock(self.lock());
            lfi
        }
    }
}

/// The seed's formal `getAudioData` on a (private) copy of a shifting-array port:
/// copies up to `max` frames from `*nfr` into `left`/`right`; returns (n, loss).
pub fn get_audio_data(
    copy: &[i32],
    nfop: usize,
    lfi: u64,
    max: usize,
    nfr: &mut u64,
    left: &mut [i32],
    right: &mut [i32],
) -> (usize, u64) {
    let ofi = (lfi + 1).saturating_sub(nfop as u64);
    let mut loss = 0;
    if *nfr < ofi {
        loss = ofi - *nfr;
        *nfr = ofi;
    }
    if *nfr > lfi {
        return (0, loss);
    }
    let n = ((lfi - *nfr + 1) as usize).min(max);
    // Frame lfi is at index nfop - 1.
    let at = nfop - 1 - (lfi - *nfr) as usize;
    left[..n].copy_from_slice(&copy[at..at + n]);
    right[..n].copy_from_slice(&copy[nfop + at..nfop + at + n]);
    *nfr += n as u64;
    (n, loss)
}
