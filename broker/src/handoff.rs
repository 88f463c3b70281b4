//! The port's backing (`--port-backing file|memfd`) and the `open-port` request: how a
//! reader gets a memfd port, which has no path.
//!
//! ```text
//!  reader                                   bassd (memfd backing)
//!   | {"request":"open-port"}           ->  |  connection already admitted: own user,
//!   |                                       |  root or --group (the port file's readers)
//!   | <- {"reply":"port-fd","epoch":7,...}  |  + SCM_RIGHTS: a new read-only description
//!   |    + one descriptor                   |    of the sealed memfd (/proc/self/fd reopen)
//! ```
//!
//! A broker with a file port answers `port-file` with the path; with no acquisition yet, an
//! `error`. Every reader gets its own open file description, so the kernel counts it like a
//! reader of a port file, and the superseded-port ledger ([`crate::pins`]) bounds the memory
//! readers pin in both backings with the same write-lease test.

use std::os::fd::{AsFd, BorrowedFd};

use bassport::control::{self, ErrorKind, PortFd, Reply};
use bassport::{memfd, Backing, PendingPort, PortParams, Writer};

use crate::capture::Acquisition;
use crate::config::Config;

/// Builds the next port in the configured backing; its epoch follows `after` (the current
/// acquisition's, or the one a predecessor left in the fd store), whatever is left at the
/// port's path: a cut or removed file says nothing. `resumable`: a memfd port a restarted
/// broker may take back (see [`Writer::prepare_memfd_resumable`]).
pub fn prepare(
    cfg: &Config,
    params: &PortParams,
    after: Option<u64>,
    resumable: bool,
) -> bassport::Result<PendingPort> {
    match cfg.port_backing {
        Backing::File => Writer::prepare(&cfg.name, params).map(|mut p| {
            p.after_epoch(after);
            p
        }),
        Backing::Memfd if resumable => Writer::prepare_memfd_resumable(&cfg.name, params, after),
        Backing::Memfd => Writer::prepare_memfd(&cfg.name, params, after),
    }
}

/// Marks the acquisition being replaced superseded: a memfd port, which no commit finds at a
/// path, and a port file the commit may not have found there (removed or replaced under the
/// broker; one the commit marked is marked again, which changes nothing).
pub fn supersede(old: &Acquisition) {
    old.supersede();
}

/// The reply to an `open-port` that did not come over a socket (no descriptor can travel).
pub fn not_on_a_socket() -> Reply {
    Reply::error(
        ErrorKind::Protocol,
        "open-port hands over a descriptor: it is answered on the control socket only",
    )
}

/// Answers `open-port` on connection `c` (whose peer was admitted by the same rule that
/// lets a user read a port file). False when the connection is finished.
pub fn serve(c: BorrowedFd<'_>, current: Option<&Acquisition>) -> bool {
    let Some(a) = current else {
        let r = Reply::error(ErrorKind::Internal, "no port: no acquisition since the broker started");
        return control::send_reply(c, &r).is_ok();
    };
    if !a.port.size_sealed() {
        let r = Reply::PortFile { port: a.port.path().to_owned() };
        return control::send_reply(c, &r).is_ok();
    }
    match memfd::reopen_read_only(a.port.file()) {
        Ok(fd) => {
            let r = Reply::PortFd(PortFd { epoch: a.port.epoch(), size: a.port.size() });
            // Our copy of the descriptor closes here; the reader's lives on in its process.
            control::send_reply_with_fd(c, &r, fd.as_fd()).is_ok()
        }
        Err(e) => {
            tracing::error!("open-port: {e}");
            let r = Reply::error(ErrorKind::Internal, &format!("cannot hand over the port: {e}"));
            control::send_reply(c, &r).is_ok()
        }
    }
}
