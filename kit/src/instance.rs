//! The instance lock: one process per name in a runtime directory, whether a broker
//! (`bassd`) or a replica writer (`bass-bridge mirror`). Both take the name the same way, so
//! neither can take over the other's control socket or port.
//!
//! ```text
//!  <runtime dir>/bass-NAME.lock   flock(LOCK_EX) held for the process's life; text: its pid,
//!                                 and `epoch N`: the last acquisition epoch a broker of this
//!                                 name started, which the next one continues (a memfd port
//!                                 leaves nothing else behind that would say it)
//!  <runtime dir>/bass-NAME.sock   control socket: replaced only by the lock's holder
//!  <runtime dir>/bass-NAME.port   the port
//! ```
//!
//! Every file is opened relative to the runtime directory's descriptor without following
//! symbolic links, created with `O_EXCL` where new, and refused if it belongs to another user
//! (docs/reliability.md, threat model). A lock file may be removed by its holder (the
//! mirror does at exit): a process that locked the removed file sees that the name no longer
//! leads to its file and takes the lock again, so two holders never coexist.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};

use bassport::paths;

/// Why a name could not be taken.
#[derive(Debug, thiserror::Error)]
pub enum InstanceError {
    /// Another live process holds the lock.
    #[error(
        "the name {name:?} is held by a running process ({holder}; lock {}, control socket {})",
        lock.display(),
        socket.display()
    )]
    Held {
        /// The name.
        name: String,
        /// `pid N (comm)` of the holder, from its lock file and /proc (escaped); or `pid unknown`.
        holder: String,
        /// Its pid when the lock file says it.
        pid: Option<u32>,
        /// The lock file.
        lock: PathBuf,
        /// The control socket of that name.
        socket: PathBuf,
    },
    /// A system broker serves the name; clients would find it first.
    #[error(
        "a system broker named {name:?} serves {}; clients would find it before this one: \
         start this one with --name OTHER",
        found.display()
    )]
    SystemName {
        /// The name.
        name: String,
        /// The system broker's file found.
        found: PathBuf,
    },
    /// Not a valid name ([`paths::check_name`]).
    #[error("{0}")]
    Name(String),
    /// A system call or a file check failed.
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The error.
        #[source]
        source: io::Error,
    },
}

fn ctx(context: impl Into<String>) -> impl FnOnce(io::Error) -> InstanceError {
    let context = context.into();
    move |source| InstanceError::Io { context, source }
}

/// A name taken in the runtime directory: the lock is held while this lives.
pub struct Instance {
    dir: OwnedFd,
    dir_path: PathBuf,
    name: String,
    lock: File,
    /// Whether taking the name removed a control socket left by a dead holder.
    pub removed_stale_socket: bool,
    /// The last epoch a holder of this name recorded ([`Instance::record_epoch`]), if any.
    pub previous_epoch: Option<u64>,
}

impl Instance {
    /// Takes the name `name` in this process's runtime directory ([`paths::runtime_dir`]).
    ///
    /// The system runtime directory (`/run/bass`, root) is created 0755 if absent and must be
    /// ours and not writable by others. A per-user process may not take a name that the
    /// system broker serves (or served: its port is still there): clients look there first.
    /// Once the lock is ours, a control socket of ours with that name was left by a process
    /// that died: it is removed.
    pub fn take(name: &str) -> Result<Instance, InstanceError> {
        paths::check_name(name).map_err(|e| InstanceError::Name(e.to_string()))?;
        let dir_path = paths::runtime_dir();
        let env_dir = std::env::var_os(paths::RUNTIME_DIR_ENV).is_some_and(|d| !d.is_empty());
        if !env_dir && dir_path == Path::new(paths::SYSTEM_RUNTIME_DIR) {
            ensure_private_dir(&dir_path).map_err(ctx("the system runtime directory"))?;
        } else if !env_dir {
            let sys = Path::new(paths::SYSTEM_RUNTIME_DIR);
            let found = ["sock", "port"]
                .map(|ext| sys.join(format!("bass-{name}.{ext}")))
                .into_iter()
                .find(|p| p.symlink_metadata().is_ok());
            if let Some(found) = found {
                return Err(InstanceError::SystemName { name: name.into(), found });
            }
        }
        Instance::take_in(&dir_path, name)
    }

    /// Takes the name `name` in directory `dir_path` (no system-directory rules).
    pub fn take_in(dir_path: &Path, name: &str) -> Result<Instance, InstanceError> {
        let dir = open_dir(dir_path)
            .map_err(ctx(format!("opening the runtime directory {}", dir_path.display())))?;
        let lock_name = format!("bass-{name}.lock");
        let (mut lock, locked) = try_lock_at(&dir, &lock_name)
            .map_err(ctx(format!("opening {}", dir_path.join(&lock_name).display())))?;
        let socket = dir_path.join(format!("bass-{name}.sock"));
        if !locked {
            let pid = read_pid(&mut lock);
            return Err(InstanceError::Held {
                name: name.into(),
                holder: describe_pid(pid),
                pid,
                lock: dir_path.join(&lock_name),
                socket,
            });
        }
        let previous_epoch = read_epoch(&mut lock);
        write_lock_text(&mut lock, previous_epoch)
            .map_err(ctx(format!("writing {}", dir_path.join(&lock_name).display())))?;
        let socket_name = format!("bass-{name}.sock");
        // We hold the lock, so any socket of ours there was left by a holder that died.
        let removed_stale_socket = remove_stale_socket_at(&dir, &socket_name)
            .map_err(ctx(format!("checking {}", socket.display())))?;
        Ok(Instance {
            dir,
            dir_path: dir_path.to_owned(),
            name: name.into(),
            lock,
            removed_stale_socket,
            previous_epoch,
        })
    }

    /// Records `epoch` in the lock file as the last acquisition epoch of this name, for the
    /// next holder's [`Instance::previous_epoch`]. Failures are ignored (the next holder then
    /// knows an older epoch, or none).
    pub fn record_epoch(&mut self, epoch: u64) {
        let _ = write_lock_text(&mut self.lock, Some(epoch));
    }

    /// The runtime directory's descriptor (every file of the instance is opened through it).
    pub fn dir(&self) -> &OwnedFd {
        &self.dir
    }

    /// The runtime directory.
    pub fn dir_path(&self) -> &Path {
        &self.dir_path
    }

    /// The name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// File name of the control socket in the directory (`bass-NAME.sock`).
    pub fn socket_name(&self) -> String {
        format!("bass-{}.sock", self.name)
    }

    /// Path of the control socket.
    pub fn socket_path(&self) -> PathBuf {
        self.dir_path.join(self.socket_name())
    }

    /// Path of the port.
    pub fn port_path(&self) -> PathBuf {
        self.dir_path.join(format!("bass-{}.port", self.name))
    }

    /// Path of the lock file.
    pub fn lock_path(&self) -> PathBuf {
        self.dir_path.join(format!("bass-{}.lock", self.name))
    }

    /// Removes our control socket, if it is still ours.
    pub fn remove_socket(&self) {
        remove_own_socket_at(&self.dir, &self.socket_name());
    }

    /// Removes the lock file (while still holding it) and releases the name.
    pub fn remove_lock(self) {
        use rustix::fs::AtFlags;
        let name = format!("bass-{}.lock", self.name);
        if same_file(&self.dir, &name, &self.lock) {
            let _ = rustix::fs::unlinkat(&self.dir, name.as_str(), AtFlags::empty());
        }
        drop(self.lock);
    }
}

/// Writes the lock file's text: this process's pid, and the last epoch if one is known.
fn write_lock_text(lock: &mut File, epoch: Option<u64>) -> io::Result<()> {
    use std::io::Seek;
    let text = match epoch {
        Some(e) => format!("{}\nepoch {e}\n", std::process::id()),
        None => format!("{}\n", std::process::id()),
    };
    lock.set_len(0)?;
    lock.seek(io::SeekFrom::Start(0))?;
    lock.write_all(text.as_bytes())
}

/// The epoch a lock file records (`epoch N` after the pid): only a number is taken.
fn read_epoch(lock: &mut File) -> Option<u64> {
    use std::io::Seek;
    let _ = lock.seek(io::SeekFrom::Start(0));
    let mut text = String::new();
    let _ = (&*lock).take(64).read_to_string(&mut text);
    let mut words = text.split_whitespace();
    words.find(|&w| w == "epoch")?;
    words.next()?.parse::<u64>().ok().filter(|&e| e < u64::MAX / 2)
}

/// The pid a lock file names: only a number is ever taken from the file (its text is not
/// echoed: another user may have written it).
fn read_pid(lock: &mut File) -> Option<u32> {
    use std::io::Seek;
    let _ = lock.seek(io::SeekFrom::Start(0));
    let mut text = String::new();
    let _ = (&*lock).take(32).read_to_string(&mut text);
    text.split_whitespace().next().and_then(|t| t.parse::<u32>().ok())
}

/// `pid N (comm)`, the command name escaped; `pid unknown` without a pid.
pub fn describe_pid(pid: Option<u32>) -> String {
    let Some(pid) = pid else { return "pid unknown".into() };
    match std::fs::read_to_string(format!("/proc/{pid}/comm")) {
        Ok(comm) => format!("pid {pid} ({})", comm.trim_end().escape_debug()),
        Err(_) => format!("pid {pid}"),
    }
}

/// Opens a directory (its fd anchors every file made there).
pub fn open_dir(dir: &Path) -> io::Result<OwnedFd> {
    use rustix::fs::{Mode, OFlags};
    Ok(rustix::fs::open(dir, OFlags::DIRECTORY | OFlags::RDONLY | OFlags::CLOEXEC, Mode::empty())?)
}

fn euid() -> u32 {
    rustix::process::geteuid().as_raw()
}

/// Creates the system runtime directory `dir` (mode 0755, owned by us) if absent, and checks
/// that it is a real directory (not a symlink) owned by us and writable by nobody else.
pub fn ensure_private_dir(dir: &Path) -> io::Result<()> {
    use rustix::fs::{FileType, Mode};
    match rustix::fs::mkdir(dir, Mode::from_raw_mode(0o755)) {
        Ok(()) | Err(rustix::io::Errno::EXIST) => {}
        Err(e) => return Err(e.into()),
    }
    let st = rustix::fs::lstat(dir)?;
    let (uid, mode) = (st.st_uid, st.st_mode);
    let problem = if FileType::from_raw_mode(mode) != FileType::Directory {
        Some("it is not a directory (a symbolic link?)".to_owned())
    } else if uid != euid() {
        Some(format!("it is owned by uid {uid}, not by this process's user ({})", euid()))
    } else if mode & 0o022 != 0 {
        Some(format!("it is writable by others (mode {:o})", mode & 0o7777))
    } else {
        None
    };
    match problem {
        Some(p) => Err(io::Error::new(io::ErrorKind::PermissionDenied, format!("{}: {p}", dir.display()))),
        None => Ok(()),
    }
}

/// Refuses a file about to be used in the runtime directory unless it is of kind `kind`,
/// owned by this process's user and not a hard link to something else.
pub fn check_own(name: &str, st: &rustix::fs::Stat, kind: rustix::fs::FileType) -> io::Result<()> {
    let found = rustix::fs::FileType::from_raw_mode(st.st_mode);
    let problem = if found != kind {
        Some(format!("it is a {found:?}, not a {kind:?}"))
    } else if st.st_uid != euid() {
        Some(format!(
            "it is owned by uid {}, not by this process's user ({}): another user may have planted it",
            st.st_uid,
            euid()
        ))
    } else if kind == rustix::fs::FileType::RegularFile && st.st_nlink != 1 {
        Some(format!("it has {} hard links", st.st_nlink))
    } else {
        None
    };
    match problem {
        Some(p) => Err(io::Error::new(io::ErrorKind::PermissionDenied, format!("refusing {name}: {p}"))),
        None => Ok(()),
    }
}

/// Whether `name` in `dir` is (still) the file `f` (same device and inode).
fn same_file(dir: &OwnedFd, name: &str, f: &File) -> bool {
    use rustix::fs::AtFlags;
    match (rustix::fs::statat(dir, name, AtFlags::SYMLINK_NOFOLLOW), rustix::fs::fstat(f)) {
        (Ok(a), Ok(b)) => a.st_dev == b.st_dev && a.st_ino == b.st_ino,
        _ => false,
    }
}

/// Opens (or creates, O_EXCL, mode 0644) the instance lock `name` in directory `dir` without
/// following symlinks, checks it is our own regular file, and takes an exclusive,
/// non-blocking `flock`; `false` if another process holds it (the file is returned for
/// reading the holder's pid). The lock lives as long as the returned file. A lock taken on
/// a file its holder removed meanwhile is given up and taken again on the new file.
pub fn try_lock_at(dir: &OwnedFd, name: &str) -> io::Result<(File, bool)> {
    use rustix::fs::{FileType, FlockOperation, Mode, OFlags};
    let flags = OFlags::RDWR | OFlags::NOFOLLOW | OFlags::CLOEXEC | OFlags::NONBLOCK;
    let mut attempts = 0;
    loop {
        attempts += 1;
        let fd = match rustix::fs::openat(
            dir,
            name,
            flags | OFlags::CREATE | OFlags::EXCL,
            Mode::from_raw_mode(0o644),
        ) {
            Ok(fd) => fd,
            Err(rustix::io::Errno::EXIST) => match rustix::fs::openat(dir, name, flags, Mode::empty()) {
                Ok(fd) => fd,
                // Removed between the two opens (its holder left): try again.
                Err(rustix::io::Errno::NOENT) if attempts < 16 => continue,
                Err(rustix::io::Errno::LOOP) => {
                    return Err(io::Error::new(
                        io::ErrorKind::PermissionDenied,
                        format!("refusing {name}: it is a symbolic link (remove it; nothing was written)"),
                    ))
                }
                Err(e) => return Err(e.into()),
            },
            Err(e) => return Err(e.into()),
        };
        check_own(name, &rustix::fs::fstat(&fd)?, FileType::RegularFile)?;
        let f = File::from(fd);
        let locked = loop {
            match rustix::fs::flock(&f, FlockOperation::NonBlockingLockExclusive) {
                Ok(()) => break true,
                Err(rustix::io::Errno::WOULDBLOCK) => break false,
                Err(rustix::io::Errno::INTR) => continue,
                Err(e) => return Err(e.into()),
            }
        };
        if locked && !same_file(dir, name, &f) && attempts < 16 {
            continue; // we locked a file its holder removed: the name leads elsewhere now.
        }
        return Ok((f, locked));
    }
}

/// Removes a control socket `name` left in `dir` by a process of ours that died; refuses
/// anything else there (a symlink, another user's file). Absent is fine. Only the holder of
/// the name's lock may call this.
pub fn remove_stale_socket_at(dir: &OwnedFd, name: &str) -> io::Result<bool> {
    use rustix::fs::{AtFlags, FileType};
    match rustix::fs::statat(dir, name, AtFlags::SYMLINK_NOFOLLOW) {
        Ok(st) => {
            check_own(name, &st, FileType::Socket)?;
            rustix::fs::unlinkat(dir, name, AtFlags::empty())?;
            Ok(true)
        }
        Err(rustix::io::Errno::NOENT) => Ok(false),
        Err(e) => Err(e.into()),
    }
}

/// Removes our control socket `name` from `dir` at exit, if it is still ours.
pub fn remove_own_socket_at(dir: &OwnedFd, name: &str) {
    use rustix::fs::{AtFlags, FileType};
    if let Ok(st) = rustix::fs::statat(dir, name, AtFlags::SYMLINK_NOFOLLOW) {
        if check_own(name, &st, FileType::Socket).is_ok() {
            let _ = rustix::fs::unlinkat(dir, name, AtFlags::empty());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("bass-instance-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_taken_name_is_refused_with_the_holders_pid_and_free_again_after_removal() {
        let d = tmp("held");
        let a = Instance::take_in(&d, "x").unwrap();
        // flock locks belong to the open file description: a second open in this process
        // conflicts like another process would.
        match Instance::take_in(&d, "x") {
            Err(InstanceError::Held { pid, holder, .. }) => {
                assert_eq!(pid, Some(std::process::id()));
                assert!(holder.starts_with(&format!("pid {}", std::process::id())), "{holder}");
            }
            other => panic!("second take: {:?}", other.map(|_| ())),
        }
        assert!(d.join("bass-x.lock").exists());
        a.remove_lock();
        assert!(!d.join("bass-x.lock").exists());
        let b = Instance::take_in(&d, "x").unwrap();
        assert_eq!(
            std::fs::read_to_string(d.join("bass-x.lock")).unwrap().trim(),
            std::process::id().to_string()
        );
        drop(b);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_lock_file_removed_by_its_holder_is_made_again_and_locked_where_the_name_leads() {
        let d = tmp("removed");
        let dir = open_dir(&d).unwrap();
        let (old, locked) = try_lock_at(&dir, "bass-y.lock").unwrap();
        assert!(locked);
        std::fs::remove_file(d.join("bass-y.lock")).unwrap();
        // The old holder still holds its (removed) file: the name is free all the same.
        let (f, locked) = try_lock_at(&dir, "bass-y.lock").unwrap();
        drop(old);
        assert!(locked && same_file(&dir, "bass-y.lock", &f));
        std::fs::remove_dir_all(&d).unwrap();
    }
}
