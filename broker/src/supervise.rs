//! bassd under a service manager (systemd): the notify protocol (READY, STATUS, WATCHDOG,
//! STOPPING) and the file descriptor store that lets a restarted bassd take its port back.
//!
//! ```text
//!  bassd 1   acquisition starts ──► FDSTORE=1 FDNAME=bass-port        + the port (read-write)
//!                               ──► FDSTORE=1 FDNAME=bass-acquisition + a memfd: what to resume
//!            SIGTERM / crash / watchdog kill: the port stays "capturing" (restart_grace_ms)
//!  systemd   keeps both descriptors across the restart (FileDescriptorStoreMax=)
//!  bassd 2   LISTEN_FDS=2 LISTEN_FDNAMES=bass-port:bass-acquisition
//!            same command line? resume: same port, same epoch, the missed frames as GAP
//!            another command line? the old port is superseded, a new acquisition starts
//! ```
//!
//! Without `NOTIFY_SOCKET` (bassd started by hand) nothing here does anything, and a
//! restart is what it always was. The store is emptied (FDSTOREREMOVE) by a Stop, so a
//! broker restarted after a Stop starts afresh.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom, Write};
use std::os::fd::{AsFd, OwnedFd};

use bassport::control::AcquireRequest;
use sd_notify::NotifyState;
use serde::{Deserialize, Serialize};

/// The store's name for the port's descriptor.
pub const PORT_FD_NAME: &str = "bass-port";
/// The store's name for the memfd holding [`Stored`].
pub const STATE_FD_NAME: &str = "bass-acquisition";
/// Default `--restart-grace-ms`: how long readers wait for a restarted broker.
pub const DEFAULT_RESTART_GRACE_MS: u32 = 10_000;
/// The largest [`Stored`] record read back (it is a few hundred bytes).
const MAX_STORED_BYTES: u64 = 64 * 1024;

/// What a broker leaves in the store besides its port: enough to resume the acquisition.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stored {
    /// Version of this record (1).
    pub version: u32,
    /// Broker name.
    pub name: String,
    /// The broker's arguments (without the program path, so that an upgrade of the binary
    /// resumes): a successor started with other arguments begins a new acquisition.
    pub config: Vec<String>,
    /// The acquisition to resume, as it was requested.
    pub request: AcquireRequest,
    /// The port's epoch.
    pub epoch: u64,
}

/// A port a predecessor left in the store, with its record (validated: names, version).
pub struct Handed {
    /// The port, open read-write.
    pub port: File,
    /// What it was capturing.
    pub stored: Stored,
}

/// This broker's arguments as [`Stored::config`] records them.
pub fn config_fingerprint() -> Vec<String> {
    std::env::args().skip(1).collect()
}

/// The broker's side of the service manager.
pub struct Supervisor {
    /// `NOTIFY_SOCKET` is set: the service manager listens.
    notify: bool,
    /// Restart grace written into ports (0: the fd store is not used).
    grace_ms: u32,
    /// Watchdog ping interval (half of WATCHDOG_USEC), if the watchdog is on.
    ping_ns: Option<u64>,
    last_ping_ns: u64,
    last_status_ns: u64,
    last_status: String,
    /// The store holds the running acquisition's port.
    holds_port: bool,
}

impl Supervisor {
    /// A broker with no service manager (tests, and a bassd started by hand).
    pub fn none() -> Supervisor {
        Supervisor {
            notify: false,
            grace_ms: 0,
            ping_ns: None,
            last_ping_ns: 0,
            last_status_ns: 0,
            last_status: String::new(),
            holds_port: false,
        }
    }

    /// The service manager named by the environment (`NOTIFY_SOCKET`, `WATCHDOG_USEC`,
    /// `FDSTORE`), if any. `grace_ms` (`--restart-grace-ms`) 0 turns the fd store off; so does
    /// `FDSTORE=0` (systemd 254 and later say how many descriptors the store takes).
    pub fn from_env(grace_ms: u32) -> Supervisor {
        let mut s = Supervisor::none();
        s.notify = std::env::var_os("NOTIFY_SOCKET").is_some_and(|v| !v.is_empty());
        if !s.notify {
            return s;
        }
        let store_off = std::env::var("FDSTORE").is_ok_and(|v| v.trim() == "0");
        s.grace_ms = if store_off { 0 } else { grace_ms };
        if s.grace_ms > 0 {
            // Nothing can take the port back through a socket nobody listens on: readers of a
            // broker that dies are then told at once, not after the grace.
            if let Err(why) = probe_notify_socket() {
                tracing::warn!(
                    "NOTIFY_SOCKET is not usable ({why}): the fd store is not used, a restart \
                     ends the acquisition (restart_grace_ms 0)"
                );
                s.grace_ms = 0;
            }
        }
        let mut usec = 0;
        if sd_notify::watchdog_enabled(false, &mut usec) && usec > 0 {
            s.ping_ns = Some(usec.saturating_mul(1000) / 2);
        }
        tracing::info!(
            fd_store = s.grace_ms > 0,
            restart_grace_ms = s.grace_ms,
            watchdog_ms = s.ping_ns.map(|p| 2 * p / 1_000_000),
            "running under a service manager"
        );
        s
    }

    /// Whether a service manager listens (`NOTIFY_SOCKET`).
    pub fn active(&self) -> bool {
        self.notify
    }

    /// The restart grace to write into new and resumed ports (0: none).
    pub fn restart_grace_ms(&self) -> u32 {
        self.grace_ms
    }

    /// Whether the store holds the running acquisition's port.
    pub fn holds_port(&self) -> bool {
        self.holds_port
    }

    /// Takes what a predecessor left in the store (`LISTEN_FDS`/`LISTEN_FDNAMES`), if it is
    /// a port and its record for broker `name`. Descriptors of any other name are closed;
    /// a record that does not parse is logged and ignored (the broker starts afresh).
    pub fn take_handed(&mut self, name: &str) -> Option<Handed> {
        let fds = match sd_notify::listen_fds_with_names(true) {
            Ok(fds) => fds,
            Err(e) => {
                tracing::warn!("LISTEN_FDS from the service manager not usable: {e}");
                return None;
            }
        };
        let (mut port, mut state) = (None, None);
        for (raw, fd_name) in fds {
            // From listen_fds_with_names(true): passed to this process, the variables unset.
            let fd = crate::os::adopt_listen_fd(raw);
            match fd_name.as_str() {
                PORT_FD_NAME if port.is_none() => port = Some(File::from(fd)),
                STATE_FD_NAME if state.is_none() => state = Some(File::from(fd)),
                other => {
                    tracing::warn!(name = other, "closing a descriptor of unknown name from the fd store")
                }
            }
        }
        let (port, state) = match (port, state) {
            (Some(p), Some(s)) => (p, s),
            (None, None) => return None,
            _ => {
                tracing::warn!("the fd store holds only one of the port and its record: starting afresh");
                self.forget();
                return None;
            }
        };
        match read_stored(state, name) {
            Ok(stored) => Some(Handed { port, stored }),
            Err(e) => {
                tracing::warn!("the fd store's acquisition record is not usable ({e}): starting afresh");
                self.forget();
                None
            }
        }
    }

    /// Hands the running acquisition's port (a read-write descriptor) and its record to the
    /// store, replacing what was there. Logged, not fatal, if the manager refuses; false then
    /// (and for a broker that does not use the store): nothing can take the port back, so the
    /// caller sets its restart grace to 0, as every later port's ([`Supervisor::restart_grace_ms`]).
    pub fn store(&mut self, port: OwnedFd, stored: &Stored) -> bool {
        if !self.notify || self.grace_ms == 0 {
            return false;
        }
        self.forget();
        let record = match write_record(stored) {
            Ok(f) => f,
            Err(e) => {
                tracing::warn!("cannot write the acquisition record for the fd store: {e}");
                self.grace_ms = 0;
                return false;
            }
        };
        let sent = sd_notify::notify_with_fds(
            false,
            &[NotifyState::FdStore, NotifyState::FdName(PORT_FD_NAME)],
            &[port.as_fd()],
        )
        .and_then(|()| {
            sd_notify::notify_with_fds(
                false,
                &[NotifyState::FdStore, NotifyState::FdName(STATE_FD_NAME)],
                &[record.as_fd()],
            )
        });
        match sent {
            Ok(()) => {
                self.holds_port = true;
                tracing::debug!(epoch = stored.epoch, "port handed to the service manager's fd store");
                true
            }
            Err(e) => {
                tracing::warn!(
                    "cannot hand the port to the service manager's fd store ({e}): restart_grace_ms 0"
                );
                self.grace_ms = 0;
                false
            }
        }
    }

    /// Empties the store (a Stop, a port that cannot be resumed).
    pub fn forget(&mut self) {
        self.holds_port = false;
        if !self.notify {
            return;
        }
        for name in [PORT_FD_NAME, STATE_FD_NAME] {
            let _ = sd_notify::notify(false, &[NotifyState::FdStoreRemove, NotifyState::FdName(name)]);
        }
    }

    /// READY=1 with a first STATUS.
    pub fn ready(&mut self, status: &str) {
        if self.notify {
            let _ = sd_notify::notify(false, &[NotifyState::Ready, NotifyState::Status(status)]);
            self.last_status = status.to_owned();
        }
    }

    /// STOPPING=1.
    pub fn stopping(&self) {
        if self.notify {
            let _ = sd_notify::notify(false, &[NotifyState::Stopping]);
        }
    }

    /// Whether a STATUS is due (once a second).
    pub fn status_due(&self, now_ns: u64) -> bool {
        self.notify && now_ns.saturating_sub(self.last_status_ns) >= 1_000_000_000
    }

    /// When [`Supervisor::tick`] has something to send next (CLOCK_MONOTONIC ns): the next
    /// STATUS check and, while `healthy`, the next watchdog ping. None without a service
    /// manager.
    pub fn next_due_ns(&self, healthy: bool) -> Option<u64> {
        if !self.notify {
            return None;
        }
        let status = self.last_status_ns.saturating_add(1_000_000_000);
        let ping = self.ping_ns.filter(|_| healthy).map_or(u64::MAX, |p| self.last_ping_ns.saturating_add(p));
        Some(status.min(ping))
    }

    /// Called on every control-loop tick: WATCHDOG=1 while `healthy` (the capture makes
    /// progress, or nothing is capturing) at half the watchdog interval, and `status` (when
    /// [`Supervisor::status_due`]) if it changed.
    pub fn tick(&mut self, now_ns: u64, healthy: bool, status: Option<String>) {
        if !self.notify {
            return;
        }
        if let Some(ping) = self.ping_ns {
            if healthy && now_ns.saturating_sub(self.last_ping_ns) >= ping {
                self.last_ping_ns = now_ns;
                let _ = sd_notify::notify(false, &[NotifyState::Watchdog]);
            }
        }
        if let Some(s) = status {
            self.last_status_ns = now_ns;
            if s != self.last_status {
                let _ = sd_notify::notify(false, &[NotifyState::Status(&s)]);
                self.last_status = s;
            }
        }
    }
}

/// Whether `NOTIFY_SOCKET` names a datagram socket something listens on (a path, or `@name`
/// in the abstract namespace): a connect of an unbound datagram socket, which sends nothing.
/// A missing path, a regular file, a stream socket, an unbound abstract name all fail here.
fn probe_notify_socket() -> Result<(), String> {
    use std::os::linux::net::SocketAddrExt;
    use std::os::unix::net::{SocketAddr, UnixDatagram};
    let target = std::env::var_os("NOTIFY_SOCKET").unwrap_or_default();
    let bytes = std::os::unix::ffi::OsStrExt::as_bytes(target.as_os_str());
    let addr = match bytes.strip_prefix(b"@") {
        Some(name) => SocketAddr::from_abstract_name(name),
        None => SocketAddr::from_pathname(std::path::Path::new(&target)),
    }
    .map_err(|e| format!("{}: {e}", target.to_string_lossy()))?;
    let sock = UnixDatagram::unbound().map_err(|e| format!("socket: {e}"))?;
    sock.connect_addr(&addr).map_err(|e| format!("{}: {e}", target.to_string_lossy()))
}

/// The record, in a memfd (the store takes descriptors, not bytes).
fn write_record(stored: &Stored) -> std::io::Result<File> {
    let fd = rustix::fs::memfd_create(STATE_FD_NAME, rustix::fs::MemfdFlags::CLOEXEC)?;
    let mut f = File::from(fd);
    f.write_all(&serde_json::to_vec(stored).map_err(std::io::Error::other)?)?;
    Ok(f)
}

/// Reads and checks a record left in the store for broker `name`.
fn read_stored(mut f: File, name: &str) -> Result<Stored, String> {
    f.seek(SeekFrom::Start(0)).map_err(|e| format!("seek: {e}"))?;
    let mut text = Vec::new();
    f.take(MAX_STORED_BYTES + 1).read_to_end(&mut text).map_err(|e| format!("read: {e}"))?;
    if text.len() as u64 > MAX_STORED_BYTES {
        return Err(format!("over {MAX_STORED_BYTES} bytes"));
    }
    let stored: Stored = serde_json::from_slice(&text).map_err(|e| format!("not a record: {e}"))?;
    if stored.version != 1 {
        return Err(format!("record version {} (this bassd writes 1)", stored.version));
    }
    if stored.name != name {
        return Err(format!("record of broker {:?}, this is broker {name:?}", stored.name));
    }
    Ok(stored)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record() -> Stored {
        Stored {
            version: 1,
            name: "default".into(),
            config: vec!["--acquire".into(), "sim:pattern".into()],
            request: AcquireRequest { device: "sim:pattern".into(), ..AcquireRequest::default() },
            epoch: 3,
        }
    }

    #[test]
    fn a_record_round_trips_through_its_memfd() {
        let f = write_record(&record()).unwrap();
        assert_eq!(read_stored(f, "default").unwrap(), record());
    }

    #[test]
    fn a_record_of_another_broker_or_version_or_garbage_is_refused_by_name() {
        let e = read_stored(write_record(&record()).unwrap(), "mics").unwrap_err();
        assert!(e.contains("\"default\"") && e.contains("\"mics\""), "{e}");
        let old = Stored { version: 7, ..record() };
        let e = read_stored(write_record(&old).unwrap(), "default").unwrap_err();
        assert!(e.contains("version 7"), "{e}");
        let mut junk = File::from(rustix::fs::memfd_create("junk", rustix::fs::MemfdFlags::CLOEXEC).unwrap());
        junk.write_all(b"{\"version\": 1, \"name\": ").unwrap();
        assert!(read_stored(junk, "default").unwrap_err().contains("not a record"));
    }

    #[test]
    fn without_a_service_manager_nothing_is_sent_or_stored() {
        let mut s = Supervisor::none();
        assert!(!s.store(write_record(&record()).unwrap().into(), &record()));
        assert!(!s.holds_port());
        assert_eq!(s.restart_grace_ms(), 0);
    }
}
