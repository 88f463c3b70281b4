//! A device open in progress: the Acquire's device is opened and configured on a worker
//! thread, so that no device can wedge the control loop.
//!
//! ```text
//!  control loop                          worker "bassd-open"
//!   Acquire: checks, port prepared  ──►  open_device(...)   (may never return: a stopped
//!   connection parked, loop goes on        │                 sound server, a plugin)
//!   poll(..., wake eventfd, ...)     ◄──  result on a channel + eventfd signalled
//!   finish: switch ports, reply          (or the deadline passes: the Acquire is refused,
//!                                         the worker is left behind; whatever it opens
//!                                         later is dropped, it never reaches a port)
//! ```
//!
//! At most one open is pending (a second Acquire is refused while one is); Status says
//! `starting` meanwhile; Stop and SIGTERM cancel it. Workers still stuck in a device after
//! their Acquire was answered are counted, and new Acquires are refused beyond
//! [`MAX_STUCK_OPENS`] so that a dead device cannot make the broker pile up threads.

use std::os::fd::{AsFd, OwnedFd, RawFd};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{mpsc, Arc};
use std::time::Duration;

use bassport::control::{self, AcquireRequest, Reply};
use bassport::sys::monotonic_ns;
use bassport::{PendingPort, Writer};

use crate::device::{alsa::OpenError, Capture};
use crate::os::EventFd;
use crate::request::Checked;

pub use crate::config::DEFAULT_OPEN_TIMEOUT;

/// Most device-open threads alive at once (stuck ones included); beyond, Acquires are refused.
pub const MAX_STUCK_OPENS: usize = 4;

/// The outcome of a device open.
pub(super) type Opened = Result<Box<dyn Capture>, OpenError>;

/// A connection whose Acquire waits for its device: the loop neither reads nor idles it out.
pub(super) struct Parked {
    /// The connection's id (see `Conn::id`).
    pub id: u64,
    /// A duplicate of its descriptor, for the reply.
    pub fd: OwnedFd,
}

/// One device open running on a worker thread.
pub(super) struct OpenJob {
    rx: mpsc::Receiver<Opened>,
    wake: Arc<EventFd>,
    /// CLOCK_MONOTONIC (ns) when it started, and when it is given up.
    pub started_ns: u64,
    pub deadline_ns: u64,
}

/// What polling an open found.
pub(super) enum Poll {
    /// Still opening, within its bound.
    Pending,
    /// The open returned (or its thread died: an error).
    Done(Opened),
    /// The bound passed; the worker is left behind.
    TimedOut,
}

impl OpenJob {
    /// Starts `open` on a worker thread; `live` counts the workers alive (decremented when
    /// one returns, however late).
    pub fn spawn(
        open: impl FnOnce() -> Opened + Send + 'static,
        timeout: Duration,
        live: &Arc<AtomicUsize>,
    ) -> std::io::Result<OpenJob> {
        let wake = Arc::new(EventFd::new()?);
        let (tx, rx) = mpsc::channel();
        let (w, n) = (wake.clone(), live.clone());
        n.fetch_add(1, Ordering::AcqRel);
        let spawned = std::thread::Builder::new().name("bassd-open".into()).spawn(move || {
            let opened = open();
            // Nobody waits any more (timed out, cancelled): the device is dropped (closed) here.
            let _ = tx.send(opened);
            w.signal();
            n.fetch_sub(1, Ordering::AcqRel);
        });
        if let Err(e) = spawned {
            live.fetch_sub(1, Ordering::AcqRel);
            return Err(e);
        }
        let started_ns = monotonic_ns();
        let deadline_ns = started_ns.saturating_add(u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX));
        Ok(OpenJob { rx, wake, started_ns, deadline_ns })
    }

    /// The eventfd that becomes readable when the open returns (for the loop's poll).
    pub fn wake_fd(&self) -> RawFd {
        self.wake.raw()
    }

    /// Whether the open returned, failed or ran out of time.
    pub fn poll(&self, now_ns: u64) -> Poll {
        match self.rx.try_recv() {
            Ok(r) => Poll::Done(r),
            Err(mpsc::TryRecvError::Disconnected) => Poll::Done(Err(OpenError {
                code: bassport::format::error_code::INTERNAL,
                message: "the device open ended without an answer (its thread panicked)".into(),
                busy: false,
            })),
            Err(mpsc::TryRecvError::Empty) if now_ns >= self.deadline_ns => Poll::TimedOut,
            Err(mpsc::TryRecvError::Empty) => Poll::Pending,
        }
    }

    /// Milliseconds since the open started.
    pub fn elapsed_ms(&self, now_ns: u64) -> u64 {
        now_ns.saturating_sub(self.started_ns) / 1_000_000
    }
}

/// The port an Acquire will publish into.
pub(super) enum NextPort {
    /// A new port, built under a temporary name (removed if the Acquire fails).
    New(PendingPort),
    /// The port a predecessor left in the service manager's fd store, taken back: the
    /// capture picks its timeline up at `due_ns` (CLOCK_MONOTONIC of the frame after its
    /// last one), the frames missed meanwhile published as GAP.
    Resumed { writer: Writer, due_ns: u64 },
}

/// An Acquire waiting for its device: everything the switch needs once the device is open.
pub(super) struct Opening {
    /// The request as the client sent it.
    pub req: AcquireRequest,
    /// The request after the checks.
    pub checked: Checked,
    /// The port it will publish into.
    pub pending: NextPort,
    /// CLOCK_MONOTONIC (ns) of the request (for the first-chunk latency log).
    pub requested_ns: u64,
    /// The running capture was stopped to free a busy device and the open retried.
    pub freed: bool,
    /// Who gets the reply (None: the start-up Acquire, whose outcome is logged).
    pub reply_to: Option<Parked>,
    /// The open in progress.
    pub job: OpenJob,
}

/// Sends the Acquire's reply to its parked connection, or logs the start-up Acquire's outcome.
pub(super) fn answer(to: Option<Parked>, reply: &Reply) {
    match to {
        Some(p) => {
            if let Err(e) = control::send_reply(p.fd.as_fd(), reply) {
                tracing::debug!("the client of a finished Acquire is gone: {e}");
            }
        }
        None => {
            if let Reply::Error { message, .. } = reply {
                tracing::error!("start-up Acquire failed: {message}");
            }
        }
    }
}
