//! The Linux edge of the broker: eventfd, signalfd, absolute sleeps, real-time scheduling,
//! peer credentials and the instance lock. Every `unsafe` of the broker outside the ALSA
//! crate lives here.

use std::fs::File;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::path::Path;
use std::time::Duration;

fn check(r: libc::c_int) -> io::Result<libc::c_int> {
    if r < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(r)
    }
}

/// A non-blocking eventfd used to wake a thread out of `poll`.
pub struct EventFd(OwnedFd);

impl EventFd {
    /// Creates an eventfd (close-on-exec, non-blocking).
    pub fn new() -> io::Result<EventFd> {
        // SAFETY: plain eventfd(2) call; the result is checked.
        let fd = check(unsafe { libc::eventfd(0, libc::EFD_CLOEXEC | libc::EFD_NONBLOCK) })?;
        // SAFETY: `fd` is a fresh descriptor owned by nobody else.
        Ok(EventFd(unsafe { OwnedFd::from_raw_fd(fd) }))
    }

    /// Makes the eventfd readable (wakes pollers); idempotent.
    pub fn signal(&self) {
        let one: u64 = 1;
        // SAFETY: writes 8 bytes from a valid u64 to an open eventfd.
        unsafe { libc::write(self.0.as_raw_fd(), (&one as *const u64).cast(), 8) };
    }

    /// The descriptor, for `poll`.
    pub fn raw(&self) -> RawFd {
        self.0.as_raw_fd()
    }
}

/// `poll(2)` over `fds`, retrying on EINTR; `timeout` None waits forever.
pub fn poll(fds: &mut [libc::pollfd], timeout: Option<Duration>) -> io::Result<usize> {
    let ms = timeout.map_or(-1, |t| t.as_millis().min(i32::MAX as u128) as libc::c_int);
    loop {
        // SAFETY: `fds` is a valid slice of pollfd for the duration of the call.
        let r = unsafe { libc::poll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, ms) };
        if r >= 0 {
            return Ok(r as usize);
        }
        let e = io::Error::last_os_error();
        if e.kind() != io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

/// A pollfd waiting for input on `fd`.
pub fn pollin(fd: RawFd) -> libc::pollfd {
    libc::pollfd { fd, events: libc::POLLIN, revents: 0 }
}

/// Sleeps until CLOCK_MONOTONIC reaches `deadline_ns` (absolute, `TIMER_ABSTIME`).
pub fn sleep_until_mono(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: `ts` is a valid timespec; the remaining-time pointer may be null with
        // TIMER_ABSTIME.
        let r = unsafe {
            libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut())
        };
        if r != libc::EINTR {
            return;
        }
    }
}

/// Blocks SIGTERM, SIGINT and SIGHUP in this thread (and the threads it spawns later) and
/// returns a signalfd that reads them.
pub fn signalfd_for_termination() -> io::Result<OwnedFd> {
    // SAFETY: sigset_t is plain data; sigemptyset initialises it.
    let mut set: libc::sigset_t = unsafe { std::mem::zeroed() };
    // SAFETY: `set` is a valid sigset_t; the signal numbers are valid.
    unsafe {
        libc::sigemptyset(&mut set);
        libc::sigaddset(&mut set, libc::SIGTERM);
        libc::sigaddset(&mut set, libc::SIGINT);
        libc::sigaddset(&mut set, libc::SIGHUP);
    }
    // SAFETY: `set` is initialised; the old-set pointer may be null.
    let r = unsafe { libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut()) };
    if r != 0 {
        return Err(io::Error::from_raw_os_error(r));
    }
    // SAFETY: writing to a broken control connection must not kill the broker.
    unsafe { libc::signal(libc::SIGPIPE, libc::SIG_IGN) };
    // SAFETY: `set` is initialised; -1 creates a new signalfd.
    let fd = check(unsafe { libc::signalfd(-1, &set, libc::SFD_CLOEXEC | libc::SFD_NONBLOCK) })?;
    // SAFETY: `fd` is a fresh descriptor owned by nobody else.
    Ok(unsafe { OwnedFd::from_raw_fd(fd) })
}

/// Reads one signal number from a signalfd, if any is pending.
pub fn read_signal(fd: &OwnedFd) -> Option<u32> {
    // SAFETY: signalfd_siginfo is plain data.
    let mut info: libc::signalfd_siginfo = unsafe { std::mem::zeroed() };
    let size = std::mem::size_of::<libc::signalfd_siginfo>();
    // SAFETY: `info` is valid for `size` bytes; `fd` is an open signalfd.
    let r = unsafe { libc::read(fd.as_raw_fd(), (&mut info as *mut libc::signalfd_siginfo).cast(), size) };
    (r == size as isize).then_some(info.ssi_signo)
}

/// Tries SCHED_FIFO at `priority` for the calling thread.
pub fn set_realtime(priority: i32) -> io::Result<()> {
    let param = libc::sched_param { sched_priority: priority };
    // SAFETY: `param` is valid; pthread_self() is the calling thread.
    let r = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::from_raw_os_error(r))
    }
}

/// Credentials of the peer of a connected Unix socket.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Peer {
    /// Process id.
    pub pid: i32,
    /// Effective user id.
    pub uid: u32,
    /// Effective group id.
    pub gid: u32,
    /// Supplementary groups (empty where the kernel cannot tell).
    pub groups: Vec<u32>,
}

/// SO_PEERGROUPS (Linux >= 4.13; the same number on the common architectures).
const SO_PEERGROUPS: libc::c_int = 59;

/// Reads SO_PEERCRED (and SO_PEERGROUPS where available) of a connected socket.
pub fn peer_credentials(fd: RawFd) -> io::Result<Peer> {
    let mut cred = libc::ucred { pid: 0, uid: 0, gid: 0 };
    let mut len = std::mem::size_of::<libc::ucred>() as libc::socklen_t;
    // SAFETY: `cred` is valid for `len` bytes; `fd` is an open socket.
    check(unsafe {
        libc::getsockopt(
            fd,
            libc::SOL_SOCKET,
            libc::SO_PEERCRED,
            (&mut cred as *mut libc::ucred).cast(),
            &mut len,
        )
    })?;
    let mut groups = vec![0u32; 256];
    let mut glen = (groups.len() * 4) as libc::socklen_t;
    // SAFETY: `groups` is valid for `glen` bytes; failure (old kernel) leaves an empty list.
    let r = unsafe {
        libc::getsockopt(fd, libc::SOL_SOCKET, SO_PEERGROUPS, groups.as_mut_ptr().cast(), &mut glen)
    };
    groups.truncate(if r == 0 { glen as usize / 4 } else { 0 });
    Ok(Peer { pid: cred.pid, uid: cred.uid, gid: cred.gid, groups })
}

/// This process's effective user id.
pub fn euid() -> u32 {
    // SAFETY: geteuid cannot fail.
    unsafe { libc::geteuid() }
}

/// The group id of group `name` (or a number).
pub fn group_id(name: &str) -> io::Result<u32> {
    if let Ok(n) = name.parse() {
        return Ok(n);
    }
    let cname = std::ffi::CString::new(name).map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
    // SAFETY: getgrnam with a valid C string; the result is only read immediately (the
    // broker resolves groups once, at start-up, before spawning threads).
    let g = unsafe { libc::getgrnam(cname.as_ptr()) };
    if g.is_null() {
        return Err(io::Error::new(io::ErrorKind::NotFound, format!("no group named {name:?}")));
    }
    // SAFETY: non-null result of getgrnam points to a valid group entry.
    Ok(unsafe { (*g).gr_gid })
}

/// Opens the runtime directory (its fd anchors every file the broker makes there).
pub fn open_dir(dir: &Path) -> io::Result<OwnedFd> {
    use rustix::fs::{Mode, OFlags};
    Ok(rustix::fs::open(dir, OFlags::DIRECTORY | OFlags::RDONLY | OFlags::CLOEXEC, Mode::empty())?)
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
        Some(format!("it is owned by uid {uid}, not by this broker's user ({})", euid()))
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

/// Refuses a file the broker is about to use in its runtime directory unless it is of kind
/// `kind`, owned by this process's user and not a hard link to something else.
fn check_own(name: &str, st: &rustix::fs::Stat, kind: rustix::fs::FileType) -> io::Result<()> {
    let found = rustix::fs::FileType::from_raw_mode(st.st_mode);
    let problem = if found != kind {
        Some(format!("it is a {found:?}, not a {kind:?}"))
    } else if st.st_uid != euid() {
        Some(format!(
            "it is owned by uid {}, not by this broker's user ({}): another user may have planted it",
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

/// Opens (or creates, O_EXCL, mode 0644) the instance lock `name` in directory `dir` without
/// following symlinks, checks it is our own regular file, and takes an exclusive,
/// non-blocking `flock`; `Ok(None)` if another process holds it (the file is returned for
/// reading the holder's pid). The lock lives as long as the returned file.
pub fn try_lock_at(dir: &OwnedFd, name: &str) -> io::Result<(File, bool)> {
    use rustix::fs::{FileType, FlockOperation, Mode, OFlags};
    let flags = OFlags::RDWR | OFlags::NOFOLLOW | OFlags::CLOEXEC | OFlags::NONBLOCK;
    let fd = match rustix::fs::openat(
        dir,
        name,
        flags | OFlags::CREATE | OFlags::EXCL,
        Mode::from_raw_mode(0o644),
    ) {
        Ok(fd) => fd,
        Err(rustix::io::Errno::EXIST) => match rustix::fs::openat(dir, name, flags, Mode::empty()) {
            Ok(fd) => fd,
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
    loop {
        match rustix::fs::flock(&f, FlockOperation::NonBlockingLockExclusive) {
            Ok(()) => return Ok((f, true)),
            Err(rustix::io::Errno::WOULDBLOCK) => return Ok((f, false)),
            Err(rustix::io::Errno::INTR) => continue,
            Err(e) => return Err(e.into()),
        }
    }
}

/// Removes a control socket `name` left in `dir` by a broker of ours that died; refuses
/// anything else there (a symlink, another user's file). Absent is fine.
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

/// Binds and listens on a SEQPACKET socket `name` in `dir` (path `path`) created with mode
/// `mode` (through the umask: no window with looser modes, no chmod through a path), then
/// gives it to `group` without following symlinks.
pub fn listen_seqpacket_at(
    dir: &OwnedFd,
    name: &str,
    path: &Path,
    mode: u32,
    group: Option<u32>,
) -> io::Result<OwnedFd> {
    use rustix::fs::{AtFlags, FileType, Mode};
    let fd = bassclient::control::seqpacket_socket()?;
    let (addr, len) = bassclient::control::sockaddr(path)?;
    // Called at start-up, before any other thread exists: the process-wide umask is ours.
    let old = rustix::process::umask(Mode::from_raw_mode(!mode & 0o777));
    // SAFETY: `addr` is a valid sockaddr_un of `len` bytes; `fd` is open.
    let r = check(unsafe { libc::bind(fd.as_raw_fd(), (&addr as *const libc::sockaddr_un).cast(), len) });
    rustix::process::umask(old);
    r?;
    if let Some(gid) = group {
        let gid = rustix::fs::Gid::from_raw(gid);
        rustix::fs::chownat(dir, name, None, Some(gid), AtFlags::SYMLINK_NOFOLLOW)?;
    }
    check_own(name, &rustix::fs::statat(dir, name, AtFlags::SYMLINK_NOFOLLOW)?, FileType::Socket)?;
    // SAFETY: listen on a bound socket.
    check(unsafe { libc::listen(fd.as_raw_fd(), 64) })?;
    set_nonblocking(fd.as_raw_fd())?;
    Ok(fd)
}

/// Accepts one connection (close-on-exec); `Ok(None)` if none is pending.
pub fn accept(listener: RawFd) -> io::Result<Option<OwnedFd>> {
    loop {
        // SAFETY: accept4 on a listening socket; the peer address is not requested.
        let r = unsafe {
            libc::accept4(listener, std::ptr::null_mut(), std::ptr::null_mut(), libc::SOCK_CLOEXEC)
        };
        if r >= 0 {
            // SAFETY: `r` is a fresh descriptor owned by nobody else.
            return Ok(Some(unsafe { OwnedFd::from_raw_fd(r) }));
        }
        let e = io::Error::last_os_error();
        match e.kind() {
            io::ErrorKind::Interrupted => continue,
            io::ErrorKind::WouldBlock => return Ok(None),
            _ => return Err(e),
        }
    }
}

fn set_nonblocking(fd: RawFd) -> io::Result<()> {
    // SAFETY: fcntl on an open descriptor.
    let flags = check(unsafe { libc::fcntl(fd, libc::F_GETFL) })?;
    // SAFETY: fcntl on an open descriptor with valid flags.
    check(unsafe { libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) })?;
    Ok(())
}

/// Sets a send timeout on a socket, so that a client that never reads cannot block the broker.
pub fn set_send_timeout(fd: RawFd, t: Duration) -> io::Result<()> {
    let tv = libc::timeval {
        tv_sec: t.as_secs() as libc::time_t,
        tv_usec: t.subsec_micros() as libc::suseconds_t,
    };
    // SAFETY: `tv` is a valid timeval for the call; `fd` is an open socket.
    check(unsafe {
        libc::setsockopt(
            fd,
            libc::SOL_SOCKET,
            libc::SO_SNDTIMEO,
            (&tv as *const libc::timeval).cast(),
            std::mem::size_of::<libc::timeval>() as libc::socklen_t,
        )
    })?;
    Ok(())
}

/// Discards whatever the peer already sent on `fd` (before closing a refused connection,
/// so that the kernel does not turn our close into a reset that hides our reply).
pub fn drain(fd: RawFd) {
    let mut buf = [0u8; 512];
    // SAFETY: `buf` is valid for writes of its length; MSG_DONTWAIT never blocks.
    while unsafe { libc::recv(fd, buf.as_mut_ptr().cast(), buf.len(), libc::MSG_DONTWAIT) } > 0 {}
}

/// Whether an `accept` error means the process or the system ran out of descriptors (or
/// of the memory behind them): EMFILE, ENFILE, ENOBUFS, ENOMEM.
pub fn is_out_of_fds(e: &io::Error) -> bool {
    matches!(e.raw_os_error(), Some(libc::EMFILE | libc::ENFILE | libc::ENOBUFS | libc::ENOMEM))
}

/// A descriptor held in reserve (`/dev/null`, close-on-exec), given up when descriptors run
/// out so that one more connection can be accepted and told why it is refused.
pub fn spare_fd() -> io::Result<OwnedFd> {
    use rustix::fs::{Mode, OFlags};
    Ok(rustix::fs::open("/dev/null", OFlags::RDONLY | OFlags::CLOEXEC, Mode::empty())?)
}
