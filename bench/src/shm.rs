//! A shared file mapping for the raw-futex baseline and the model of the original design.

use std::fs::OpenOptions;
use std::os::fd::AsRawFd;
use std::path::Path;

/// A read-write `MAP_SHARED` mapping of a whole file.
pub struct Region {
    ptr: *mut u8,
    len: usize,
}

impl Region {
    /// Creates (or truncates) `path` to `len` zero bytes and maps it.
    pub fn create(path: &Path, len: usize) -> Region {
        let f =
            OpenOptions::new().read(true).write(true).create(true).truncate(true).open(path).expect("create");
        f.set_len(len as u64).expect("set_len");
        Region::map(&f, len)
    }

    /// Maps an existing file of `len` bytes.
    pub fn open(path: &Path, len: usize) -> Region {
        let f = OpenOptions::new().read(true).write(true).open(path).expect("open shared file");
        Region::map(&f, len)
    }

    /// Maps an existing file of `len` bytes read-only (as clients map a port).
    pub fn open_ro(path: &Path, len: usize) -> Region {
        let f = OpenOptions::new().read(true).open(path).expect("open shared file");
        Region::map_prot(&f, len, libc::PROT_READ)
    }

    fn map(f: &std::fs::File, len: usize) -> Region {
        Region::map_prot(f, len, libc::PROT_READ | libc::PROT_WRITE)
    }

    fn map_prot(f: &std::fs::File, len: usize, prot: libc::c_int) -> Region {
        // SAFETY: a fresh shared mapping of an open file descriptor with a length the file
        // has; no existing memory is affected. The result is checked against MAP_FAILED.
        let ptr = unsafe { libc::mmap(std::ptr::null_mut(), len, prot, libc::MAP_SHARED, f.as_raw_fd(), 0) };
        assert!(ptr != libc::MAP_FAILED, "mmap: {}", std::io::Error::last_os_error());
        Region { ptr: ptr as *mut u8, len }
    }

    /// Start of the mapping (page aligned).
    pub fn ptr(&self) -> *mut u8 {
        self.ptr
    }
}

impl Drop for Region {
    fn drop(&mut self) {
        // SAFETY: `ptr`/`len` are exactly what mmap returned; nothing borrows the region
        // beyond `self`'s lifetime (references handed out are tied to `&self`).
        unsafe { libc::munmap(self.ptr as *mut libc::c_void, self.len) };
    }
}

/// Waits while `*word == expected` (shared futex), at most `timeout_ns` (0 = forever).
pub fn futex_wait(word: &std::sync::atomic::AtomicU32, expected: u32, timeout_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
    };
    let tsp = if timeout_ns == 0 { std::ptr::null() } else { &ts as *const libc::timespec };
    // SAFETY: `word` is a valid aligned u32 for the call; `tsp` is null or points to `ts`,
    // which outlives the call.
    unsafe { libc::syscall(libc::SYS_futex, word.as_ptr(), libc::FUTEX_WAIT, expected, tsp, 0usize, 0u32) };
}

/// Wakes every waiter on `word`.
pub fn futex_wake(word: &std::sync::atomic::AtomicU32) {
    // SAFETY: `word` is a valid aligned u32; FUTEX_WAKE only uses its address as a key.
    unsafe {
        libc::syscall(libc::SYS_futex, word.as_ptr(), libc::FUTEX_WAKE, i32::MAX, 0usize, 0usize, 0u32)
    };
}

/// CLOCK_MONOTONIC in nanoseconds.
pub fn now_ns() -> u64 {
    bassclient::sys::monotonic_ns()
}

impl Region {
    /// The `AtomicU32` at byte offset `off`.
    pub fn u32_at(&self, off: usize) -> &std::sync::atomic::AtomicU32 {
        assert!(off % 4 == 0 && off + 4 <= self.len);
        // SAFETY: in bounds and aligned (asserted); shared memory is valid for any bit
        // pattern and lives as long as `self`; all cross-process access to it is atomic.
        unsafe { &*(self.ptr.add(off) as *const std::sync::atomic::AtomicU32) }
    }

    /// The `AtomicU64` at byte offset `off`.
    pub fn u64_at(&self, off: usize) -> &std::sync::atomic::AtomicU64 {
        assert!(off % 8 == 0 && off + 8 <= self.len);
        // SAFETY: as in `u32_at`.
        unsafe { &*(self.ptr.add(off) as *const std::sync::atomic::AtomicU64) }
    }
}
