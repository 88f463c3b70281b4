//! Ports backed by a sealed memfd instead of a file in the runtime directory.
//!
//! A regular file can be truncated under a reader's mapping (SIGBUS on the next access), so
//! a reader of a file port checks the size (`lseek`) before every access. A memfd created
//! with `MFD_ALLOW_SEALING` and sealed `F_SEAL_SHRINK | F_SEAL_GROW` cannot change size at
//! all, for anybody: a reader that sees those seals never needs the check. The port is
//! sealed once it is wholly allocated:
//!
//! ```text
//!  memfd_create(ALLOW_SEALING|CLOEXEC) -> ftruncate(len) -> fallocate(0, len) -> mmap RW
//!    -> F_ADD_SEALS(SHRINK | GROW | FUTURE_WRITE | SEAL)
//! ```
//!
//! `F_SEAL_FUTURE_WRITE` refuses every new write access (write(2), new writable mappings,
//! `mprotect` to writable) while the writer's own mapping, made before, keeps writing; and
//! `F_SEAL_SEAL` makes the set final. Readers get their own read-only open file description
//! ([`reopen_read_only`]), so each reader's descriptor (and mapping) counts separately in the
//! kernel: that is what lets the broker see, with a write lease, whether anybody still holds
//! a superseded port (broker/src/pins.rs), exactly as for port files.
//!
//! A memfd has no name in any directory: it lives only while a descriptor or a mapping of it
//! does. Readers get it from the broker over the control socket (`open-port`, SCM_RIGHTS).

use std::fs::File;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, OwnedFd};

use rustix::fs::{FallocateFlags, MemfdFlags, Mode, OFlags, SealFlags};
use rustix::io::Errno;

use crate::error::{Error, Result};
use crate::portfile::mib;

/// The seals that make a port's size final (what a reader needs to skip the size check).
pub const SIZE_SEALS: SealFlags = SealFlags::SHRINK.union(SealFlags::GROW);

/// Every seal the writer puts on its port.
pub const PORT_SEALS: SealFlags = SIZE_SEALS.union(SealFlags::FUTURE_WRITE).union(SealFlags::SEAL);

/// The name a port memfd of broker `name` is created with (`bass-port:NAME`, at most 200
/// characters): what /proc/PID/fd shows as `/memfd:bass-port:NAME (deleted)`.
pub fn label(name: &str) -> String {
    format!("bass-port:{name}").chars().filter(|c| *c != '\0').take(200).collect()
}

/// Creates an unsealed memfd of `len` bytes, every byte allocated. `name` is only a label
/// (it shows in /proc/PID/fd and /proc/PID/maps as `memfd:bass-port:NAME`).
///
/// Refused with a message saying how much memory is needed and available when the system
/// cannot hold it now (MemAvailable of /proc/meminfo), or when the allocation fails.
pub fn create(name: &str, len: u64) -> Result<File> {
    if let Some(avail) = mem_available() {
        if len > avail {
            return Err(no_memory(len, Some(avail)));
        }
    }
    let fd = rustix::fs::memfd_create(label(name).as_str(), MemfdFlags::CLOEXEC | MemfdFlags::ALLOW_SEALING)
        .map_err(|e| Error::io("memfd_create for the port", e.into()))?;
    rustix::fs::ftruncate(&fd, len)
        .map_err(|e| Error::io(format!("size the port memfd to {}", mib(len)), e.into()))?;
    match rustix::fs::fallocate(&fd, FallocateFlags::empty(), 0, len) {
        Ok(()) => {}
        Err(Errno::NOSPC | Errno::NOMEM) => return Err(no_memory(len, mem_available())),
        Err(e) => return Err(Error::io(format!("allocate {} for the port memfd", mib(len)), e.into())),
    }
    Ok(File::from(fd))
}

fn no_memory(needed: u64, avail: Option<u64>) -> Error {
    let avail = avail.map_or_else(|| "an unknown amount".to_owned(), mib);
    Error::io(
        format!(
            "the port needs {} ({needed} bytes) of memory but {avail} is available (memfd \
             backing: the port lives in RAM or swap); ask for fewer frames, chunks or channels",
            mib(needed)
        ),
        std::io::Error::from_raw_os_error(libc::ENOMEM),
    )
}

/// MemAvailable of /proc/meminfo in bytes (None when it cannot be read).
fn mem_available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// Puts [`PORT_SEALS`] on a port memfd (after it is allocated and mapped by the writer).
pub fn seal(file: &File) -> Result<()> {
    rustix::fs::fcntl_add_seals(file, PORT_SEALS).map_err(|e| Error::io("seal the port memfd", e.into()))
}

/// Seals a port memfd that a successor writer may map writable again (a broker restarted
/// with the port from systemd's fd store): [`SIZE_SEALS`] and `F_SEAL_SEAL`, not
/// `F_SEAL_FUTURE_WRITE`. In its place the memfd's mode becomes 0600, so no other user can
/// reopen a read-only descriptor it was handed (through /proc/PID/fd) for writing; only the
/// writer's own user (and root) could.
pub fn seal_resumable(file: &File) -> Result<()> {
    rustix::fs::fchmod(file, Mode::from_raw_mode(0o600))
        .map_err(|e| Error::io("chmod the port memfd 0600", e.into()))?;
    rustix::fs::fcntl_add_seals(file, SIZE_SEALS.union(SealFlags::SEAL))
        .map_err(|e| Error::io("seal the port memfd", e.into()))
}

/// Whether `fd`'s size can no longer change (it carries `F_SEAL_SHRINK` and `F_SEAL_GROW`).
/// A file that cannot carry seals (any regular file of a file system) is not sealed.
pub fn size_sealed(fd: BorrowedFd<'_>) -> bool {
    rustix::fs::fcntl_get_seals(fd).is_ok_and(|s| s.contains(SIZE_SEALS))
}

/// A new read-only open file description of the same memfd (through /proc/self/fd): what a
/// reader is handed. It cannot write, map writable or grow write access (the file's mode
/// and `F_SEAL_FUTURE_WRITE`), and, being its own description, it shows in the kernel's
/// count of openers (see [`crate::memfd`]).
pub fn reopen_read_only(fd: impl AsFd) -> Result<OwnedFd> {
    let path = format!("/proc/self/fd/{}", fd.as_fd().as_raw_fd());
    rustix::fs::open(path.as_str(), OFlags::RDONLY | OFlags::CLOEXEC, Mode::empty())
        .map_err(|e| Error::io(format!("reopen the port memfd read-only ({path})"), e.into()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::fd::AsFd;

    #[test]
    fn a_sealed_port_memfd_cannot_change_size_or_be_written_through_a_reader_descriptor() {
        let f = create("unit", 8192).unwrap();
        assert!(!size_sealed(f.as_fd()), "not sealed before seal()");
        seal(&f).unwrap();
        assert!(size_sealed(f.as_fd()));
        assert_eq!(rustix::fs::ftruncate(&f, 4096), Err(Errno::PERM), "shrink refused");
        assert_eq!(rustix::fs::ftruncate(&f, 16384), Err(Errno::PERM), "grow refused");
        let r = reopen_read_only(&f).unwrap();
        assert!(size_sealed(r.as_fd()), "the seals belong to the memfd, not to a descriptor");
        assert_eq!(rustix::io::write(&r, b"x"), Err(Errno::BADF), "a reader descriptor is read-only");
        assert_eq!(rustix::fs::fstat(&r).unwrap().st_size, 8192);
    }

    #[test]
    fn a_port_larger_than_memory_is_refused_with_a_message() {
        let e = create("huge", u64::MAX / 2).unwrap_err();
        assert!(e.to_string().contains("of memory but"), "{e}");
    }
}
