//! Control connections: accepting them (and staying alive when descriptors run out), the peer
//! check and the connection limits.

use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use bassport::control::{self, ErrorKind, Reply};
use bassport::sys::monotonic_ns;

use crate::os;

/// Most control connections open at once.
pub const MAX_CLIENTS: usize = 128;
/// Of those, how many only the broker's own user and root may take: members of `--group`
/// can hold at most `MAX_CLIENTS - RESERVED_CLIENTS`, so the operator can always get in.
pub const RESERVED_CLIENTS: usize = 8;
/// How long the broker stops accepting after running out of descriptors.
const ACCEPT_BACKOFF: Duration = Duration::from_millis(250);
/// Shortest interval between two "out of descriptors" log lines.
const EMFILE_LOG_EVERY_NS: u64 = 10_000_000_000;

/// Whether `peer` may control a broker running as `own_uid` with allowed group `group`.
pub fn peer_allowed(peer: &os::Peer, own_uid: u32, group: Option<u32>) -> bool {
    peer.uid == own_uid || peer.uid == 0 || group.is_some_and(|g| peer.gid == g || peer.groups.contains(&g))
}

/// One open control connection.
pub(super) struct Conn {
    /// Unique in this process (a pending Acquire names the connection it answers).
    pub(super) id: u64,
    pub(super) fd: OwnedFd,
    /// Peer process (for the logs).
    pub(super) pid: u32,
    /// CLOCK_MONOTONIC (ns) of the accept or of the last request.
    pub(super) last_ns: u64,
}

impl Conn {
    pub(super) fn new(fd: OwnedFd, pid: u32) -> Conn {
        static NEXT_ID: AtomicU64 = AtomicU64::new(1);
        Conn { id: NEXT_ID.fetch_add(1, Ordering::Relaxed), fd, pid, last_ns: monotonic_ns() }
    }
}

/// Accepts control connections, and keeps the broker alive when descriptors run out.
///
/// A spare descriptor is held in reserve: when `accept` fails with EMFILE/ENFILE, the
/// spare is given up to accept the waiting connection and refuse it with a message (so the
/// client learns why instead of hanging), then taken again. If even that fails, the
/// listener is not polled for [`ACCEPT_BACKOFF`]; the condition is logged at most once per
/// 10 s with the number of refusals, and accepting resumes by itself once descriptors free up.
pub(super) struct Acceptor {
    spare: Option<OwnedFd>,
    pub(super) paused_until_ns: u64,
    out_of_fds: bool,
    refused_since_log: u64,
    last_log_ns: u64,
}

impl Acceptor {
    pub(super) fn new() -> Acceptor {
        Acceptor {
            spare: os::spare_fd().ok(),
            paused_until_ns: 0,
            out_of_fds: false,
            refused_since_log: 0,
            last_log_ns: 0,
        }
    }

    pub(super) fn accept_all(
        &mut self,
        listener: BorrowedFd<'_>,
        clients: &mut Vec<Conn>,
        own_uid: u32,
        group: Option<u32>,
    ) {
        if self.spare.is_none() {
            // Lost while descriptors were short: take it again as soon as one is free.
            self.spare = os::spare_fd().ok();
        }
        loop {
            match os::accept(listener) {
                Ok(Some(c)) => {
                    if self.out_of_fds && self.spare.is_some() {
                        self.out_of_fds = false;
                        tracing::info!(
                            refused = self.refused_since_log,
                            "control connections are accepted again (file descriptors freed up)"
                        );
                        self.refused_since_log = 0;
                    }
                    admit(c, clients, own_uid, group);
                }
                Ok(None) => return,
                Err(e) if os::is_out_of_fds(&e) => {
                    self.on_out_of_fds(listener, &e);
                    return;
                }
                Err(e) => {
                    // ECONNABORTED, EPROTO and the like concern one connection: go on later.
                    tracing::debug!("accept: {e}");
                    self.paused_until_ns = monotonic_ns() + ACCEPT_BACKOFF.as_nanos() as u64;
                    return;
                }
            }
        }
    }

    fn on_out_of_fds(&mut self, listener: BorrowedFd<'_>, e: &std::io::Error) {
        let now = monotonic_ns();
        self.out_of_fds = true;
        // Refuse what waits, one connection per spare descriptor round.
        let mut refused_now = 0;
        while refused_now < 64 {
            let Some(spare) = self.spare.take() else { break };
            drop(spare);
            let accepted = os::accept(listener);
            let got_one = matches!(accepted, Ok(Some(_)));
            if let Ok(Some(c)) = &accepted {
                let m = Reply::error(
                    ErrorKind::Internal,
                    "the broker is out of file descriptors; try again later",
                );
                let _ = control::send_reply(c.as_fd(), &m);
                os::drain(c.as_fd());
                refused_now += 1;
            }
            drop(accepted);
            self.spare = os::spare_fd().ok();
            if !got_one || self.spare.is_none() {
                break;
            }
        }
        self.refused_since_log += refused_now.max(1);
        // Still out of descriptors (no spare to give up): stop watching the listener a while.
        if self.spare.is_none() || refused_now == 0 {
            self.paused_until_ns = now + ACCEPT_BACKOFF.as_nanos() as u64;
        }
        if self.last_log_ns == 0 || now.saturating_sub(self.last_log_ns) >= EMFILE_LOG_EVERY_NS {
            self.last_log_ns = now;
            tracing::warn!(
                refused = self.refused_since_log,
                "accept: {e}: out of file descriptors; refusing new control connections until some \
                 close (capture goes on; idle connections close after the idle timeout)"
            );
            self.refused_since_log = 0;
        }
    }
}

/// Checks a new connection's peer and the connection limits; keeps it or refuses it with a reply.
fn admit(c: OwnedFd, clients: &mut Vec<Conn>, own_uid: u32, group: Option<u32>) {
    let fd = c.as_fd();
    let _ = os::set_send_timeout(fd, Duration::from_secs(1));
    let peer = match os::peer_credentials(fd) {
        Ok(p) if peer_allowed(&p, own_uid, group) => Some(p),
        Ok(p) => {
            tracing::warn!(pid = p.pid, uid = p.uid, "refused a control connection (not our user or group)");
            None
        }
        Err(e) => {
            tracing::warn!("refused a control connection: SO_PEERCRED: {e}");
            None
        }
    };
    let refuse = |kind, text: &str| {
        let _ = control::send_reply(c.as_fd(), &Reply::error(kind, text));
        os::drain(fd);
    };
    let Some(peer) = peer else {
        refuse(ErrorKind::Permission, "permission denied: not the broker's user or group");
        return;
    };
    let privileged = peer.uid == own_uid || peer.uid == 0;
    let limit = if privileged { MAX_CLIENTS } else { MAX_CLIENTS - RESERVED_CLIENTS };
    if clients.len() >= limit {
        tracing::warn!(
            pid = peer.pid,
            uid = peer.uid,
            open = clients.len(),
            "refused a control connection: too many"
        );
        refuse(
            ErrorKind::Internal,
            &format!(
                "too many control connections ({} open; {RESERVED_CLIENTS} of {MAX_CLIENTS} are kept for the \
                 broker's own user and root)",
                clients.len()
            ),
        );
        return;
    }
    clients.push(Conn::new(c, peer.pid));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peers_are_allowed_by_user_root_or_group() {
        let p = |uid, gid, groups: Vec<u32>| os::Peer { pid: 1, uid, gid, groups };
        assert!(peer_allowed(&p(1000, 1000, vec![]), 1000, None));
        assert!(peer_allowed(&p(0, 0, vec![]), 1000, None));
        assert!(!peer_allowed(&p(1001, 1001, vec![]), 1000, None));
        assert!(peer_allowed(&p(1001, 29, vec![]), 1000, Some(29)));
        assert!(peer_allowed(&p(1001, 1001, vec![4, 29]), 1000, Some(29)));
        assert!(!peer_allowed(&p(1001, 1001, vec![4]), 1000, Some(29)));
    }
}
