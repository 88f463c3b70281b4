//! The port file on disk: creating, allocating and opening it safely in a runtime
//! directory that other users may be able to write (the default /dev/shm is mode 1777).
//!
//! Every name is resolved relative to a directory descriptor and never through a symbolic
//! link (`O_NOFOLLOW`, `AT_SYMLINK_NOFOLLOW`); new files are created with `O_EXCL`; an
//! existing file must be a regular file owned by the expected user. The whole file is
//! allocated when it is created (`fallocate`), so a full file system refuses the port up
//! front instead of killing its writer with SIGBUS on the first touch of an unbacked page.

use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::os::fd::OwnedFd;
use std::path::Path;
use std::sync::atomic::{AtomicU32, Ordering};

use rustix::fs::{AtFlags, FallocateFlags, FileType, Mode, OFlags};
use rustix::io::Errno;

use crate::error::{Error, Result};
use crate::paths;

/// Opens the runtime directory (the directory itself may be reached through a link:
/// that choice is the operator's, not the other users').
pub(crate) fn open_dir(dir: &Path) -> Result<OwnedFd> {
    rustix::fs::open(dir, OFlags::DIRECTORY | OFlags::RDONLY | OFlags::CLOEXEC, Mode::empty())
        .map_err(|e| Error::io(format!("open the runtime directory {}", dir.display()), e.into()))
}

/// `12.3 MiB` for messages.
pub fn mib(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / f64::from(1u32 << 20))
}

/// Refuses a port of `needed` bytes that the file system of `dir` cannot hold now.
pub(crate) fn check_space(dir: &OwnedFd, dir_path: &Path, needed: u64) -> Result<()> {
    let v = rustix::fs::fstatvfs(dir)
        .map_err(|e| Error::io(format!("statvfs of {}", dir_path.display()), e.into()))?;
    let free = v.f_bavail.saturating_mul(v.f_frsize);
    if needed > free {
        return Err(no_space(dir_path, needed, free));
    }
    Ok(())
}

fn no_space(dir_path: &Path, needed: u64, free: u64) -> Error {
    Error::io(
        format!(
            "the port needs {} ({needed} bytes) but only {} is free in {} (the runtime directory; \
             set {} to a larger file system, or ask for fewer frames, chunks or channels)",
            mib(needed),
            mib(free),
            dir_path.display(),
            paths::RUNTIME_DIR_ENV
        ),
        std::io::Error::from_raw_os_error(libc::ENOSPC),
    )
}

/// Opens an existing port file `name` in `dir` for writing, if there is one: refuses a
/// symbolic link, anything but a regular file, and a file this process's user does not own.
/// Returns the file and its length.
pub(crate) fn open_existing(dir: &OwnedFd, name: &str, path: &Path) -> Result<Option<(File, u64)>> {
    let st = match rustix::fs::statat(dir, name, AtFlags::SYMLINK_NOFOLLOW) {
        Ok(st) => st,
        Err(Errno::NOENT) => return Ok(None),
        Err(e) => return Err(Error::io(format!("stat {}", path.display()), e.into())),
    };
    check_kind_and_owner(&st, dir, name, path)?;
    // No O_CREAT: the name was there; O_NOFOLLOW and O_NONBLOCK in case it was swapped for
    // a link or a FIFO since the stat; the file is checked again through the descriptor.
    let fd = match rustix::fs::openat(
        dir,
        name,
        OFlags::RDWR | OFlags::NOFOLLOW | OFlags::NONBLOCK | OFlags::CLOEXEC,
        Mode::empty(),
    ) {
        Ok(fd) => fd,
        Err(Errno::NOENT) => return Ok(None),
        Err(Errno::LOOP) => return Err(symlink_refused(dir, name, path)),
        Err(e) => return Err(Error::io(format!("open {}", path.display()), e.into())),
    };
    let st = rustix::fs::fstat(&fd).map_err(|e| Error::io(format!("fstat {}", path.display()), e.into()))?;
    check_kind_and_owner(&st, dir, name, path)?;
    Ok(Some((File::from(fd), st.st_size as u64)))
}

fn check_kind_and_owner(st: &rustix::fs::Stat, dir: &OwnedFd, name: &str, path: &Path) -> Result<()> {
    match FileType::from_raw_mode(st.st_mode) {
        FileType::RegularFile => {}
        FileType::Symlink => return Err(symlink_refused(dir, name, path)),
        other => {
            return Err(Error::InvalidArgument(format!(
                "refusing to use {}: it is a {other:?}, not a regular file (remove it)",
                path.display()
            )))
        }
    }
    let own = rustix::process::geteuid().as_raw();
    if st.st_uid != own {
        return Err(Error::InvalidArgument(format!(
            "refusing to replace {}: it is owned by {}, not by this writer ({}); another user may \
             have created it in place of the port — remove it, or use a runtime directory only the \
             broker can write ({})",
            path.display(),
            paths::describe_uid(st.st_uid),
            paths::describe_uid(own),
            paths::RUNTIME_DIR_ENV
        )));
    }
    Ok(())
}

fn symlink_refused(dir: &OwnedFd, name: &str, path: &Path) -> Error {
    let target = rustix::fs::readlinkat(dir, name, Vec::new())
        .map(|t| format!(" (to {:?})", t.to_string_lossy()))
        .unwrap_or_default();
    Error::InvalidArgument(format!(
        "refusing to use {}: it is a symbolic link{target}; a port file is never opened through a \
         link — remove it, or use a runtime directory only the broker can write ({})",
        path.display(),
        paths::RUNTIME_DIR_ENV
    ))
}

/// Removes temporary port files of `name` left by writers that died while building one
/// (`.NAME.PID.N.tmp` of a PID that no longer exists, regular files of our own user only):
/// they are wholly allocated, so leaving them would eat the runtime directory's space.
pub(crate) fn remove_stale_temps(dir: &OwnedFd, dir_path: &Path, name: &str) {
    let Ok(entries) = std::fs::read_dir(dir_path) else { return };
    let prefix = format!(".{name}.");
    let own = rustix::process::geteuid().as_raw();
    for e in entries.flatten() {
        let file = e.file_name();
        let Some(f) = file.to_str() else { continue };
        let Some(pid) = f
            .strip_prefix(&prefix)
            .and_then(|r| r.strip_suffix(".tmp"))
            .and_then(|r| r.split('.').next())
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        if pid == std::process::id() || Path::new(&format!("/proc/{pid}")).exists() {
            continue;
        }
        let ours = rustix::fs::statat(dir, f, AtFlags::SYMLINK_NOFOLLOW)
            .is_ok_and(|st| st.st_uid == own && FileType::from_raw_mode(st.st_mode) == FileType::RegularFile);
        if ours {
            let _ = rustix::fs::unlinkat(dir, f, AtFlags::empty());
        }
    }
}

/// Creates a new temporary file next to `name` (`O_EXCL`, `O_NOFOLLOW`, mode 0640).
pub(crate) fn create_temp(dir: &OwnedFd, dir_path: &Path, name: &str) -> Result<(String, File)> {
    static SEQ: AtomicU32 = AtomicU32::new(0);
    let mut last = None;
    for _ in 0..8 {
        let tmp = format!(".{name}.{}.{}.tmp", std::process::id(), SEQ.fetch_add(1, Ordering::Relaxed));
        match rustix::fs::openat(
            dir,
            tmp.as_str(),
            OFlags::RDWR | OFlags::CREATE | OFlags::EXCL | OFlags::NOFOLLOW | OFlags::CLOEXEC,
            Mode::from_raw_mode(0o640),
        ) {
            Ok(fd) => return Ok((tmp, File::from(fd))),
            // Planted or left over: never reuse it, try the next name.
            Err(Errno::EXIST) => last = Some(Errno::EXIST),
            Err(e) => {
                return Err(Error::io(format!("create {}", dir_path.join(&tmp).display()), e.into()));
            }
        }
    }
    Err(Error::io(
        format!("create a temporary port file in {}", dir_path.display()),
        last.unwrap_or(Errno::EXIST).into(),
    ))
}

/// Mode 0640 (whatever the umask did) and the group, if one is configured.
pub(crate) fn set_mode_group(file: &File, group: Option<u32>) -> Result<()> {
    rustix::fs::fchmod(file, Mode::from_raw_mode(0o640))
        .map_err(|e| Error::io("chmod 0640 of the port file", e.into()))?;
    if let Some(gid) = group {
        let gid = rustix::fs::Gid::from_raw(gid);
        rustix::fs::fchown(file, None, Some(gid))
            .map_err(|e| Error::io(format!("chown of the port file to group {gid:?}"), e.into()))?;
    }
    Ok(())
}

/// Sizes the file to `len` bytes and allocates every byte of it, so no page of the port is
/// ever a hole that a full file system could fail to back (SIGBUS in the writer).
pub(crate) fn allocate(file: &File, dir_path: &Path, len: u64) -> Result<()> {
    match rustix::fs::fallocate(file, FallocateFlags::empty(), 0, len) {
        Ok(()) => Ok(()),
        Err(Errno::NOSPC) => {
            let free = rustix::fs::fstatvfs(file).map(|v| v.f_bavail.saturating_mul(v.f_frsize)).unwrap_or(0);
            Err(no_space(dir_path, len, free))
        }
        // A file system without fallocate: write the zeros (the same guarantee, slower).
        Err(Errno::OPNOTSUPP) => write_zeros(file, dir_path, len),
        Err(e) => Err(Error::io(format!("allocate {} for the port file", mib(len)), e.into())),
    }
}

fn write_zeros(file: &File, dir_path: &Path, len: u64) -> Result<()> {
    let zeros = vec![0u8; 1 << 20];
    let mut f = file;
    f.seek(SeekFrom::Start(0)).map_err(|e| Error::io("seek in the port file", e))?;
    let mut left = len;
    while left > 0 {
        let n = left.min(zeros.len() as u64) as usize;
        if let Err(e) = f.write_all(&zeros[..n]) {
            if e.raw_os_error() == Some(libc::ENOSPC) {
                return Err(no_space(dir_path, len, len - left));
            }
            return Err(Error::io(format!("write {} of zeros into the port file", mib(len)), e));
        }
        left -= n as u64;
    }
    Ok(())
}
