//! A shared file mapping for the raw-futex baseline and the model of the original design
//! (the futex and clock calls are the library's: `bassport::sys`).

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
