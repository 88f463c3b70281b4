//! Pacing: waiting for a CLOCK_MONOTONIC deadline within microseconds, and a stop that ends
//! the wait at once. bassd's simulated and replayed devices are paced by it, and the bench
//! measures the same code as bassd's timer (so the bench needs no broker).

use std::os::fd::{AsRawFd, OwnedFd, RawFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use rustix::event::{EventfdFlags, PollFd, PollFlags};
use rustix::io::Errno;
use rustix::time::Timespec;

/// Asks a capture thread to stop: a flag for loops that sleep, an eventfd for loops that poll.
pub struct StopSignal {
    flag: AtomicBool,
    efd: OwnedFd,
}

impl StopSignal {
    /// A fresh, unsignalled stop signal.
    pub fn new() -> std::io::Result<StopSignal> {
        let efd = rustix::event::eventfd(0, EventfdFlags::CLOEXEC | EventfdFlags::NONBLOCK)?;
        Ok(StopSignal { flag: AtomicBool::new(false), efd })
    }

    /// Signals the stop (idempotent).
    pub fn signal(&self) {
        self.flag.store(true, Ordering::Release);
        // EAGAIN (the counter is full) still leaves the eventfd readable: nothing to do.
        let _ = rustix::io::write(&self.efd, &1u64.to_ne_bytes());
    }

    /// Whether the stop was signalled.
    pub fn is_set(&self) -> bool {
        self.flag.load(Ordering::Acquire)
    }

    /// The eventfd, readable once the stop is signalled.
    pub fn fd(&self) -> RawFd {
        self.efd.as_raw_fd()
    }
}

/// Timer slack of the capture thread, in ns: the kernel may delay a timed wake-up of the
/// thread by up to this much, to batch it with other timers. The default (50 µs, inherited
/// from the parent thread) was the largest part of a simulated device's delay; 1 ns (the
/// smallest a thread can ask for; 0 means "the default") removes it.
pub const CAPTURE_TIMER_SLACK_NS: u64 = 1;

/// Sets the calling thread's timer slack to [`CAPTURE_TIMER_SLACK_NS`]
/// (`prctl(PR_SET_TIMERSLACK)`), so that its timed waits — [`sleep_until`]'s sleeps and polls,
/// an ALSA `poll`'s timeout — end when they are due. Called once by the capture thread. A
/// SCHED_FIFO thread has no slack anyway; this is for the capture thread that runs without.
///
/// Measured on the bench machine (2-core VM), the sleep below with 50 µs slack: wake-up p50
/// 65–74 µs after the deadline; with 1 ns: 13–21 µs, at the same CPU per wake.
pub fn precise_timers() -> std::io::Result<()> {
    let slack = std::num::NonZeroU64::new(CAPTURE_TIMER_SLACK_NS);
    Ok(rustix::thread::set_current_timer_slack(slack)?)
}

/// The longest wait [`sleep_until`] spends in one absolute sleep, which a stop does not end:
/// a stop waits at most this long. Every chunk period up to it (50 chunks a second and more)
/// costs the capture thread one wake-up.
pub const ONE_SLEEP_MAX_NS: u64 = 20_000_000;

/// Sleeps until CLOCK_MONOTONIC `deadline` (ns) and returns false as soon as the stop fires
/// (true at the deadline). A wait of at most [`ONE_SLEEP_MAX_NS`] is one absolute-deadline
/// sleep (a stop is seen when it ends); a longer one waits in `poll` on the stop's eventfd
/// until 1 ms before the deadline, then sleeps the rest. The pacing of the simulated and
/// replayed devices; called on the capture thread, whose timer slack [`precise_timers`] has
/// set to 1 ns, so the sleep ends within µs of the deadline.
///
/// One wake-up per chunk, not two: the pacing used to poll until 1 ms before every deadline
/// and sleep the last stretch, a second sleep that woke 5–7 µs closer to the deadline (from
/// a vCPU lightly idle) but cost a wake-up, ~25 µs of CPU on a VM whose idle is HLT only.
/// Measured in part 7 of the bench (Intel Xeon VM, 2026-12-04, 256-frame chunks): timer part
/// p50 34–42 µs with two wake-ups, 40–50 µs with one (PipeWire's timerfd in the same runs
/// 39–54 µs); bassd's CPU at one client 0.84–1.15 % of a core with two, 0.43–0.72 % with one
/// (pipewire 0.50–0.75 %). An absolute `timerfd` polled with the eventfd (interruptible, one
/// wake-up) was measured earlier at the same lateness as one sleep, plus a syscall.
pub fn sleep_until(deadline: u64, stop: &StopSignal) -> bool {
    const LEAD_NS: u64 = 1_000_000;
    loop {
        if stop.is_set() {
            return false;
        }
        let now = bassport::sys::monotonic_ns();
        if now >= deadline {
            return true;
        }
        let remaining = deadline - now;
        if remaining > ONE_SLEEP_MAX_NS {
            let mut fds = [PollFd::new(&stop.efd, PollFlags::IN)];
            let wait = Duration::from_nanos(remaining - LEAD_NS);
            let timeout = Timespec { tv_sec: wait.as_secs() as i64, tv_nsec: wait.subsec_nanos() as _ };
            // EINTR: the loop looks again.
            let _ = rustix::event::poll(&mut fds, Some(&timeout));
        } else {
            sleep_until_mono(deadline);
        }
    }
}

/// Sleeps until CLOCK_MONOTONIC reaches `deadline_ns` (absolute, `TIMER_ABSTIME`).
pub fn sleep_until_mono(deadline_ns: u64) {
    let ts = Timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as i64,
        tv_nsec: (deadline_ns % 1_000_000_000) as _,
    };
    while let Err(Errno::INTR) =
        rustix::thread::clock_nanosleep_absolute(rustix::thread::ClockId::Monotonic, &ts)
    {}
}
