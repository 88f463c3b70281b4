//! The timer probes of part 7: a thread sleeping with each system's timer, whose wake-up
//! minus target is the timer's part of a client's delay.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bassport::sys::monotonic_ns;

use super::daemon::{Sched, RT_DAEMON};
use crate::e2e::cpu_ns;

/// The probes' sleeps: a random 3–6 ms, so that their wake-ups fall at every phase of the
/// daemon's cycle (a probe locked to one phase could sit in the burst of woken clients every
/// time, or never) and its median is the timer's own latency on the machine as loaded.
pub(super) fn probe_gap() -> u64 {
    fastrand::u64(3_000_000..6_000_000)
}

/// Timer probe, PipeWire's way: an absolute timerfd on CLOCK_MONOTONIC, waited for in `poll`.
pub(super) fn probe_timerfd(stop: &AtomicBool) -> Vec<f64> {
    use rustix::time::{
        timerfd_create, timerfd_settime, Itimerspec, TimerfdClockId, TimerfdFlags, TimerfdTimerFlags,
    };
    let Ok(fd) = timerfd_create(TimerfdClockId::Monotonic, TimerfdFlags::CLOEXEC) else { return Vec::new() };
    let mut out = Vec::new();
    let mut due = monotonic_ns() + probe_gap();
    while !stop.load(Ordering::Acquire) {
        let ts = |ns: u64| rustix::time::Timespec {
            tv_sec: (ns / 1_000_000_000) as i64,
            tv_nsec: (ns % 1_000_000_000) as _,
        };
        let spec = Itimerspec { it_interval: ts(0), it_value: ts(due) };
        if timerfd_settime(&fd, TimerfdTimerFlags::ABSTIME, &spec).is_err() {
            break;
        }
        let mut fds = [rustix::event::PollFd::new(&fd, rustix::event::PollFlags::IN)];
        let _ = rustix::event::poll(&mut fds, None);
        out.push(monotonic_ns().saturating_sub(due) as f64);
        let mut buf = [0u8; 8];
        let _ = rustix::io::read(&fd, &mut buf);
        due = monotonic_ns() + probe_gap();
    }
    out
}

/// Timer probe, bassd's way: its capture thread's `device::sleep_until`, without timer slack.
pub(super) fn probe_bass_pacing(stop: &AtomicBool) -> Vec<f64> {
    let _ = basskit::pacing::precise_timers();
    let Ok(never) = basskit::pacing::StopSignal::new() else { return Vec::new() };
    let mut out = Vec::new();
    let mut due = monotonic_ns() + probe_gap();
    while !stop.load(Ordering::Acquire) {
        basskit::pacing::sleep_until(due, &never);
        out.push(monotonic_ns().saturating_sub(due) as f64);
        due = monotonic_ns() + probe_gap();
    }
    out
}

/// Measures CPU of the daemon and the clients over `secs` seconds and runs `probe` meanwhile;
/// returns (window, daemon CPU, clients CPU, probe samples).
pub(super) fn window(
    daemon: u32,
    clients: &[u32],
    secs: f64,
    sched: Sched,
    probe: impl FnOnce(&AtomicBool) -> Vec<f64> + Send,
) -> ((u64, u64), f64, f64, Vec<f64>) {
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        let h = s.spawn(|| {
            // The probe sleeps as the daemon's thread does: at its priority in the realtime run.
            if sched == Sched::Fifo {
                let _ = bassport::sys::sched::set_fifo(RT_DAEMON as i32);
            }
            probe(&stop)
        });
        let sum = |p: &[u32]| p.iter().map(|&p| cpu_ns(p)).sum::<u64>();
        let (d0, c0, t0, m0) = (cpu_ns(daemon), sum(clients), Instant::now(), monotonic_ns());
        std::thread::sleep(Duration::from_secs_f64(secs));
        let (d1, c1, wall, m1) =
            (cpu_ns(daemon), sum(clients), t0.elapsed().as_nanos() as f64, monotonic_ns());
        stop.store(true, Ordering::Release);
        let timer = h.join().expect("probe thread");
        ((m0, m1), d1.saturating_sub(d0) as f64 / wall, c1.saturating_sub(c0) as f64 / wall, timer)
    })
}
