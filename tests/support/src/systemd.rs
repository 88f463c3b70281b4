//! The service manager's side of sd_notify and the file descriptor store, faked for tests
//! that cannot boot systemd: a datagram socket `NOTIFY_SOCKET` names, receiving the
//! broker's state lines and the descriptors it hands over (SCM_RIGHTS), a store applying
//! `FDSTORE=1`/`FDSTOREREMOVE=1` with `FDNAME=` as systemd does, and the hand-back
//! (`LISTEN_FDS`, `LISTEN_FDNAMES`, `LISTEN_PID`) through [`crate::BassdBuilder::handed_fds`].
//! The real systemd is tested by tests/systemd/run.sh (`make test-systemd`).

use std::io::IoSliceMut;
use std::mem::MaybeUninit;
use std::os::fd::OwnedFd;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rustix::net::{RecvAncillaryBuffer, RecvAncillaryMessage, RecvFlags};

/// One datagram: its lines and when it came.
#[derive(Debug, Clone)]
pub struct Notice {
    /// The datagram's text (`KEY=VALUE` lines).
    pub text: String,
    /// When the fake received it.
    pub at: Instant,
    /// How many descriptors came with it.
    pub fds: usize,
}

impl Notice {
    /// Whether one of its lines is exactly `line`.
    pub fn has(&self, line: &str) -> bool {
        self.text.lines().any(|l| l == line)
    }

    /// The value of `KEY=` in it, if any.
    pub fn value(&self, key: &str) -> Option<&str> {
        self.text.lines().find_map(|l| l.strip_prefix(key)?.strip_prefix('='))
    }
}

/// The fake service manager.
pub struct FakeManager {
    path: PathBuf,
    sock: UnixDatagram,
    /// The fd store: (FDNAME, descriptor), in the order stored.
    pub store: Vec<(String, OwnedFd)>,
    /// Every datagram received.
    pub notices: Vec<Notice>,
}

impl FakeManager {
    /// Listens on `DIR/notify`.
    pub fn new(dir: &Path) -> FakeManager {
        let path = dir.join("notify");
        let sock = UnixDatagram::bind(&path).expect("bind the fake NOTIFY_SOCKET");
        FakeManager { path, sock, store: Vec::new(), notices: Vec::new() }
    }

    /// The environment a service gets: `NOTIFY_SOCKET`, and `WATCHDOG_USEC` if given.
    pub fn env(&self, watchdog_usec: Option<u64>) -> Vec<(String, String)> {
        let mut env = vec![("NOTIFY_SOCKET".to_owned(), self.path.display().to_string())];
        if let Some(us) = watchdog_usec {
            env.push(("WATCHDOG_USEC".to_owned(), us.to_string()));
        }
        env
    }

    /// Receives one datagram within `timeout`, applying its store commands.
    pub fn recv(&mut self, timeout: Duration) -> Option<Notice> {
        self.sock.set_read_timeout(Some(timeout.max(Duration::from_millis(1)))).ok()?;
        let mut buf = vec![0u8; 4096];
        let mut space = [MaybeUninit::<u8>::uninit(); rustix::cmsg_space!(ScmRights(8))];
        let mut control = RecvAncillaryBuffer::new(&mut space);
        let msg = rustix::net::recvmsg(
            &self.sock,
            &mut [IoSliceMut::new(&mut buf)],
            &mut control,
            RecvFlags::CMSG_CLOEXEC,
        )
        .ok()?;
        let mut fds: Vec<OwnedFd> = Vec::new();
        for m in control.drain() {
            if let RecvAncillaryMessage::ScmRights(rights) = m {
                fds.extend(rights);
            }
        }
        let n = Notice {
            text: String::from_utf8_lossy(&buf[..msg.bytes]).into_owned(),
            at: Instant::now(),
            fds: fds.len(),
        };
        if n.has("FDSTOREREMOVE=1") {
            let name = n.value("FDNAME").unwrap_or("stored").to_owned();
            self.store.retain(|(s, _)| *s != name);
        }
        if n.has("FDSTORE=1") {
            let name = n.value("FDNAME").unwrap_or("stored").to_owned();
            self.store.extend(fds.into_iter().map(|fd| (name.clone(), fd)));
        }
        self.notices.push(n.clone());
        Some(n)
    }

    /// Receives until a datagram has line `line` (returned) or `timeout` passes (None).
    pub fn wait_for(&mut self, line: &str, timeout: Duration) -> Option<Notice> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.checked_duration_since(Instant::now())?;
            if let Some(n) = self.recv(left) {
                if n.has(line) {
                    return Some(n);
                }
            }
        }
    }

    /// Receives everything that comes within `period`.
    pub fn collect(&mut self, period: Duration) -> Vec<Notice> {
        let deadline = Instant::now() + period;
        let mut got = Vec::new();
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            if let Some(n) = self.recv(left) {
                got.push(n);
            }
        }
        got
    }

    /// The names in the store, in order.
    pub fn stored_names(&self) -> Vec<&str> {
        self.store.iter().map(|(n, _)| n.as_str()).collect()
    }

    /// Duplicates of the stored descriptors, to hand to the next start of the service.
    pub fn handed(&self) -> Vec<(String, OwnedFd)> {
        self.store
            .iter()
            .map(|(n, fd)| (n.clone(), fd.try_clone().expect("dup a stored descriptor")))
            .collect()
    }
}
