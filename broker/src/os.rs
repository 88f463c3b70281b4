//! The Linux edge of the broker: eventfd, termination signals, absolute sleeps, real-time
//! scheduling, peer credentials and the control socket's listener (the instance lock is
//! `basskit::instance`, shared with `bass-bridge mirror`).
//! System calls go through rustix (and signal-hook for the signals); the few `unsafe`
//! blocks left are calls neither wraps (SO_PEERGROUPS, getgrnam, a write lease, an fd from the
//! service manager); SCHED_FIFO is `bassport::sys::sched`'s.

use std::io;
use std::os::fd::{AsRawFd, BorrowedFd, OwnedFd, RawFd};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use rustix::io::Errno;

/// A non-blocking eventfd used to wake a thread out of `poll`.
pub struct EventFd(OwnedFd);

impl EventFd {
    /// Creates an eventfd (close-on-exec, non-blocking).
    pub fn new() -> io::Result<EventFd> {
        use rustix::event::EventfdFlags;
        Ok(EventFd(rustix::event::eventfd(0, EventfdFlags::CLOEXEC | EventfdFlags::NONBLOCK)?))
    }

    /// Makes the eventfd readable (wakes pollers); idempotent.
    pub fn signal(&self) {
        // EAGAIN (the counter is full) still leaves the eventfd readable: nothing to do.
        let _ = rustix::io::write(&self.0, &1u64.to_ne_bytes());
    }

    /// The descriptor, for `poll`.
    pub fn raw(&self) -> RawFd {
        self.0.as_raw_fd()
    }
}

/// `poll(2)` over `fds`, retrying on EINTR; `timeout` None waits forever. Raw `pollfd`s,
/// because ALSA hands out its descriptors that way; the call is the alsa crate's wrapper.
pub fn poll(fds: &mut [libc::pollfd], timeout: Option<Duration>) -> io::Result<usize> {
    let ms = timeout.map_or(-1, |t| t.as_millis().min(i32::MAX as u128) as i32);
    loop {
        match alsa::poll::poll(fds, ms) {
            Ok(n) => return Ok(n),
            // The alsa crate keeps poll's errno negated, as ALSA's own codes are.
            Err(e) if e.errno().abs() == libc::EINTR => continue,
            Err(e) => return Err(io::Error::from_raw_os_error(e.errno().abs())),
        }
    }
}

/// A pollfd waiting for input on `fd`.
pub fn pollin(fd: RawFd) -> libc::pollfd {
    libc::pollfd { fd, events: libc::POLLIN, revents: 0 }
}

/// SIGTERM, SIGINT and SIGHUP, caught: a pollable descriptor that becomes readable when
/// one arrives, and the number of the last one.
pub struct TermSignals {
    wake: UnixStream,
    last: Arc<AtomicUsize>,
}

impl AsRawFd for TermSignals {
    fn as_raw_fd(&self) -> RawFd {
        self.wake.as_raw_fd()
    }
}

/// Catches SIGTERM, SIGINT and SIGHUP (through signal-hook: the handler records the signal
/// and writes to a socket pair the control loop polls), and ignores SIGPIPE (writing to a
/// broken control connection must not kill the broker).
pub fn catch_termination_signals() -> io::Result<TermSignals> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGPIPE, SIGTERM};
    let (wake, write) = UnixStream::pair()?;
    wake.set_nonblocking(true)?;
    write.set_nonblocking(true)?;
    let last = Arc::new(AtomicUsize::new(0));
    for sig in [SIGTERM, SIGINT, SIGHUP] {
        // Registered in this order, the actions run in this order: the number is stored
        // before the wake-up is written.
        signal_hook::flag::register_usize(sig, Arc::clone(&last), sig as usize)?;
        signal_hook::low_level::pipe::register(sig, write.try_clone()?)?;
    }
    signal_hook::flag::register(SIGPIPE, Arc::new(AtomicBool::new(false)))?;
    Ok(TermSignals { wake, last })
}

/// The termination signal that arrived, if any (drains the wake-ups).
pub fn read_signal(s: &TermSignals) -> Option<u32> {
    let mut buf = [0u8; 64];
    while matches!(rustix::io::read(&s.wake, &mut buf), Ok(n) if n > 0) {}
    match s.last.swap(0, Ordering::AcqRel) {
        0 => None,
        sig => u32::try_from(sig).ok(),
    }
}

/// Tries SCHED_FIFO at `priority` for the calling thread.
pub fn set_realtime(priority: i32) -> io::Result<()> {
    bassport::sys::sched::set_fifo(priority).map_err(io::Error::from_raw_os_error)
}

/// Credentials of the peer of a connected Unix socket.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Peer {
    /// Process id (0: not visible in the broker's pid namespace, e.g. a client outside the
    /// broker's container).
    pub pid: u32,
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
pub fn peer_credentials(fd: BorrowedFd<'_>) -> io::Result<Peer> {
    let cred = bassport::control::peer_credentials(fd)?;
    let mut groups = vec![0u32; 256];
    let mut glen = (groups.len() * 4) as libc::socklen_t;
    // SAFETY: `groups` is valid for `glen` bytes; `fd` is an open socket; failure (old
    // kernel) leaves an empty list. rustix has no SO_PEERGROUPS.
    let r = unsafe {
        libc::getsockopt(
            fd.as_raw_fd(),
            libc::SOL_SOCKET,
            SO_PEERGROUPS,
            groups.as_mut_ptr().cast(),
            &mut glen,
        )
    };
    groups.truncate(if r == 0 { glen as usize / 4 } else { 0 });
    Ok(Peer { pid: cred.pid, uid: cred.uid, gid: cred.gid, groups })
}

/// This process's effective user id.
pub fn euid() -> u32 {
    rustix::process::geteuid().as_raw()
}

/// The group id of group `name` (or a number).
pub fn group_id(name: &str) -> io::Result<u32> {
    if let Ok(n) = name.parse() {
        return Ok(n);
    }
    let cname = std::ffi::CString::new(name).map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
    // SAFETY: getgrnam with a valid C string; the result is only read immediately (the
    // broker resolves groups once, at start-up, before spawning threads). rustix has no
    // name service calls.
    let g = unsafe { libc::getgrnam(cname.as_ptr()) };
    if g.is_null() {
        return Err(io::Error::new(io::ErrorKind::NotFound, format!("no group named {name:?}")));
    }
    // SAFETY: non-null result of getgrnam points to a valid group entry.
    Ok(unsafe { (*g).gr_gid })
}

// The instance lock and the runtime directory's file checks are shared with
// `bass-bridge mirror`, which takes its replica's name the same way: libbassclient.
use basskit::instance::check_own;

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
    let fd = bassport::control::seqpacket_socket()?;
    let addr = bassport::control::socket::unix_addr(path)?;
    // Called at start-up, before any other thread exists: the process-wide umask is ours.
    let old = rustix::process::umask(Mode::from_raw_mode(!mode & 0o777));
    let r = rustix::net::bind(&fd, &addr);
    rustix::process::umask(old);
    r?;
    if let Some(gid) = group {
        let gid = rustix::fs::Gid::from_raw(gid);
        rustix::fs::chownat(dir, name, None, Some(gid), AtFlags::SYMLINK_NOFOLLOW)?;
    }
    check_own(name, &rustix::fs::statat(dir, name, AtFlags::SYMLINK_NOFOLLOW)?, FileType::Socket)?;
    rustix::net::listen(&fd, 64)?;
    rustix::io::ioctl_fionbio(&fd, true)?;
    Ok(fd)
}

/// Accepts one connection (close-on-exec); `Ok(None)` if none is pending.
pub fn accept(listener: BorrowedFd<'_>) -> io::Result<Option<OwnedFd>> {
    loop {
        match rustix::net::accept_with(listener, rustix::net::SocketFlags::CLOEXEC) {
            Ok(fd) => return Ok(Some(fd)),
            Err(Errno::INTR) => continue,
            Err(Errno::WOULDBLOCK) => return Ok(None),
            Err(e) => return Err(e.into()),
        }
    }
}

/// Sets a send timeout on a socket, so that a client that never reads cannot block the broker.
pub fn set_send_timeout(fd: BorrowedFd<'_>, t: Duration) -> io::Result<()> {
    bassport::control::socket::set_timeouts(fd, None, Some(t))
}

/// Discards whatever the peer already sent on `fd` (before closing a refused connection,
/// so that the kernel does not turn our close into a reset that hides our reply).
pub fn drain(fd: BorrowedFd<'_>) {
    let mut buf = [0u8; 512];
    while matches!(rustix::net::recv(fd, &mut buf[..], rustix::net::RecvFlags::DONTWAIT), Ok((_, n)) if n > 0)
    {
    }
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

/// Whether another open file (a reader's descriptor or mapping) refers to the inode of `fd`:
/// a write lease (F_SETLEASE) is granted only while nobody else has the file open.
pub fn held_elsewhere(fd: BorrowedFd<'_>) -> io::Result<bool> {
    let fd = fd.as_raw_fd();
    // SAFETY: fcntl(F_SETLEASE) on a descriptor borrowed for the call, with an int argument;
    // no memory is passed. The lease is released at once below (a write lease exists only
    // while no one else has the file open, so nobody can be waiting to break it).
    if unsafe { libc::fcntl(fd, libc::F_SETLEASE, libc::F_WRLCK) } == 0 {
        // SAFETY: as above.
        unsafe { libc::fcntl(fd, libc::F_SETLEASE, libc::F_UNLCK) };
        return Ok(false);
    }
    let e = io::Error::last_os_error();
    match e.raw_os_error() {
        Some(libc::EAGAIN) | Some(libc::EBUSY) => Ok(true),
        _ => Err(e),
    }
}

/// Takes ownership of a descriptor the service manager passed to this process (LISTEN_FDS).
/// The caller must have it from `sd_notify::listen_fds_with_names(true)`, which checked that
/// LISTEN_PID is ours and unset the variables, so that nothing else takes it.
pub fn adopt_listen_fd(raw: RawFd) -> OwnedFd {
    use std::os::fd::FromRawFd;
    // SAFETY: per the contract above, the descriptor is open, was passed to this process and
    // is owned by nobody else in it: we own it from here on.
    unsafe { OwnedFd::from_raw_fd(raw) }
}
