//! The calling thread's scheduling: SCHED_FIFO for bassd's capture thread, a callback
//! stream's thread and the bench, and putting back what was there before (libc: rustix has no
//! wrapper for the scheduling policy).

/// Puts the scheduling of [`Sched`] back when dropped (None: nothing to put back).
pub struct Restore(pub Option<Sched>);

impl Drop for Restore {
    fn drop(&mut self) {
        if let Some(s) = self.0.take() {
            s.restore();
        }
    }
}

/// The calling thread's scheduling policy and priority, as [`Sched::current`] found them.
#[derive(Clone, Copy)]
pub struct Sched {
    policy: libc::c_int,
    priority: libc::c_int,
}

impl Sched {
    /// The calling thread's policy and priority (None if the kernel does not say).
    pub fn current() -> Option<Sched> {
        // SAFETY: pid 0 is the calling thread; no pointer is passed.
        let policy = unsafe { libc::sched_getscheduler(0) };
        let mut param = libc::sched_param { sched_priority: 0 };
        // SAFETY: `param` is a valid, writable sched_param for the duration of the call.
        let r = unsafe { libc::sched_getparam(0, &mut param) };
        (policy >= 0 && r == 0).then_some(Sched { policy, priority: param.sched_priority })
    }

    /// Puts the calling thread back to this policy and priority (lowering a priority needs no
    /// privilege; a failure leaves the thread as it is).
    pub fn restore(self) {
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
