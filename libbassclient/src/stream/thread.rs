//! A stream on a thread of its own: the handle that stops and joins it, and SCHED_FIFO.

use std::thread::JoinHandle;

use super::{Stopper, Stream};
use crate::error::Result;

/// A stream running on its own thread ([`Stream::spawn`]).
pub struct StreamHandle {
    pub(super) stopper: Stopper,
    pub(super) thread: Option<JoinHandle<(Stream, Result<()>)>>,
}

impl StreamHandle {
    /// Asks the stream to stop (from any thread); [`StreamHandle::join`] waits for it.
    pub fn stop(&self) {
        self.stopper.stop();
    }

    /// A stop handle that can be moved into a callback or another thread.
    pub fn stopper(&self) -> Stopper {
        self.stopper.clone()
    }

    /// The id of the stream's thread (None once joined).
    pub fn thread_id(&self) -> Option<std::thread::ThreadId> {
        self.thread.as_ref().map(|t| t.thread().id())
    }

    /// Whether the stream's thread has ended (a callback stopped it, or an error).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().map_or(true, |t| t.is_finished())
    }

    /// Waits for the stream to end (without asking it to) and gives it back with how its run
    /// ended. A panic in a callback is resumed here.
    pub fn join(mut self) -> (Stream, Result<()>) {
        let thread = self.thread.take().expect("joined once");
        thread.join().unwrap_or_else(|p| std::panic::resume_unwind(p))
    }
}

impl Drop for StreamHandle {
    /// Stops and joins the stream. A callback's panic is not dropped silently: it is resumed
    /// here, as [`StreamHandle::join`] would (unless this thread is already unwinding). How a
    /// run that ended by an error ended is given only by `join`.
    fn drop(&mut self) {
        if let Some(t) = self.thread.take() {
            self.stopper.stop();
            if let Err(p) = t.join() {
                if !std::thread::panicking() {
                    std::panic::resume_unwind(p);
                }
            }
        }
    }
}

/// Puts the scheduling of [`Sched`] back when dropped (None: nothing to put back).
pub(super) struct Restore(pub(super) Option<Sched>);

impl Drop for Restore {
    fn drop(&mut self) {
        if let Some(s) = self.0.take() {
            s.restore();
        }
    }
}

/// The calling thread's scheduling policy and priority, as [`Sched::current`] found them.
#[derive(Clone, Copy)]
pub(super) struct Sched {
    policy: libc::c_int,
    priority: libc::c_int,
}

impl Sched {
    /// The calling thread's policy and priority (None if the kernel does not say).
    pub(super) fn current() -> Option<Sched> {
        // SAFETY: pid 0 is the calling thread; no pointer is passed.
        let policy = unsafe { libc::sched_getscheduler(0) };
        let mut param = libc::sched_param { sched_priority: 0 };
        // SAFETY: `param` is a valid, writable sched_param for the duration of the call.
        let r = unsafe { libc::sched_getparam(0, &mut param) };
        (policy >= 0 && r == 0).then_some(Sched { policy, priority: param.sched_priority })
    }

    /// Puts the calling thread back to this policy and priority (lowering a priority needs no
    /// privilege; a failure leaves the thread as it is).
    pub(super) fn restore(self) {
        let param = libc::sched_param { sched_priority: self.priority };
        // SAFETY: `param` is a valid sched_param for the duration of the call; pid 0 is the
        // calling thread.
        let _ = unsafe { libc::sched_setscheduler(0, self.policy, &param) };
    }
}

/// Puts the calling thread in `SCHED_FIFO` at `priority`; Err(errno) when refused.
pub fn set_fifo(priority: i32) -> std::result::Result<(), i32> {
    let param = libc::sched_param { sched_priority: priority };
    // SAFETY: `param` is a valid sched_param for the duration of the call; pid 0 is the
    // calling thread.
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error().raw_os_error().unwrap_or(libc::EPERM))
    }
}
