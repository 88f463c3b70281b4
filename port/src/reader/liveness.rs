//! Is the port's writer still there? Answered without reading /proc on every call.
//!
//! The header names its writer by pid and start time. The first question about a writer
//! opens a pidfd for its pid and then checks, once, in /proc that the pid still has that
//! start time: if it does, the pidfd is that very process (a recycled pid would show another
//! start time), and from then on one `poll` of the pidfd (readable once the process has
//! ended) answers. A writer found dead stays dead: a (pid, start time) pair never lives
//! again. Where /proc cannot tell (no /proc entry for the pid, or no start time to pin it to),
//! every question falls back to [`sys::writer_alive`]. A writer in another pid namespace
//! never gets here: its pid means nothing in ours, and `Port::writer_alive` judges it by its
//! heartbeat (`writer_pid_ns` in the header).
//!
//! A writer replaced by its successor (a broker restarted with the same port, see
//! `restart_grace_ms` in docs/port-format.md) changes the pid and start time in the header:
//! the next question opens a new pidfd.

use std::os::fd::OwnedFd;
use std::sync::Mutex;

use rustix::event::{PollFd, PollFlags};
use rustix::process::{Pid, PidfdFlags};

use std::sync::atomic::Ordering::{Acquire, Relaxed};

use super::FOREIGN_WRITER_SILENCE;
use crate::error::{Error, Result};
use crate::format;
use crate::sys;

/// What is known about one writer (pid, start time).
enum Known {
    /// Alive when last asked; the pidfd says when it ends.
    Watched(OwnedFd),
    /// Ended: it never comes back.
    Dead,
    /// /proc cannot tell (no entry, or no start time): asked again every time.
    Unknown,
}

/// The cache of one port's writer liveness (shared by the threads using the port).
#[derive(Default)]
pub(crate) struct WriterWatch {
    cached: Mutex<Option<(u32, u64, Known)>>,
}

impl WriterWatch {
    /// Whether the writer `pid` that started at `start_time` is running: one `poll` of a
    /// pidfd once it is known, else what [`sys::writer_alive`] says.
    pub(crate) fn alive(&self, pid: u32, start_time: u64) -> bool {
        let mut cached = self.cached.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((p, s, known)) = cached.as_mut() {
            if (*p, *s) == (pid, start_time) {
                return match known {
                    Known::Watched(fd) => {
                        if ended(fd) {
                            *known = Known::Dead;
                            false
                        } else {
                            true
                        }
                    }
                    Known::Dead => false,
                    Known::Unknown => sys::writer_alive(pid, start_time),
                };
            }
        }
        let (alive, known) = first_look(pid, start_time);
        *cached = Some((pid, start_time, known));
        alive
    }
}

/// Opens the writer's pidfd, then checks in /proc that the pid is still the writer.
fn first_look(pid: u32, start_time: u64) -> (bool, Known) {
    let Some(p) = i32::try_from(pid).ok().and_then(Pid::from_raw) else {
        return (false, Known::Dead);
    };
    // The pidfd first: if /proc shows the writer's start time after it was opened, the
    // pidfd cannot be another process's.
    let pidfd = rustix::process::pidfd_open(p, PidfdFlags::empty()).ok();
    match sys::process_start(pid) {
        Some((start, state)) => {
            let alive = state != 'Z' && state != 'X' && (start_time == 0 || start == start_time);
            match (alive, pidfd) {
                (true, Some(fd)) if start_time != 0 => (true, Known::Watched(fd)),
                // No start time to pin the pid to, or no pidfd: ask every time.
                (true, _) => (true, Known::Unknown),
                (false, _) => (false, Known::Dead),
            }
        }
        None => (sys::writer_alive(pid, start_time), Known::Unknown),
    }
}

/// Whether the process of `pidfd` has ended (the descriptor is readable then).
fn ended(pidfd: &OwnedFd) -> bool {
    let mut fds = [PollFd::new(pidfd, PollFlags::IN)];
    let zero = rustix::event::Timespec { tv_sec: 0, tv_nsec: 0 };
    match rustix::event::poll(&mut fds, Some(&zero)) {
        Ok(n) => n > 0 && !fds[0].revents().is_empty(),
        // EINTR and the like: not an answer; the process is taken as alive until asked again.
        Err(_) => false,
    }
}

/// The port's questions about its writer: alive, gone for good, or replaced by a successor.
impl super::Port {
    /// `WriterGone` if the writer process is gone for good (see [`Port::writer_gone`]);
    /// `Restarted` if it is dead and its broker serves another acquisition (see
    /// [`Port::replaced_by_successor`]).
    pub(super) fn check_writer_alive(&self) -> Result<()> {
        let now = sys::monotonic_ns();
        if self.writer_alive(|| now) {
            return Ok(());
        }
        if self.replaced_by_successor() {
            return Err(Error::Restarted);
        }
        match self.writer_gone(now) {
            None => Ok(()),
            Some(pid) => Err(Error::WriterGone { pid }),
        }
    }

    /// For a memfd port whose writer is dead: whether the broker that handed it over now
    /// serves a memfd port of another epoch (a successor that started a new acquisition
    /// without taking this port back, so nobody can mark it superseded). One request on the
    /// broker's control socket; false at once for a port file (its successor's commit marks
    /// it) and for a descriptor of unknown origin.
    pub(crate) fn replaced_by_successor(&self) -> bool {
        let Some(name) = &self.broker else { return false };
        crate::control::client::broker_memfd_epoch(name).is_some_and(|e| e != self.epoch)
    }

    /// Whether the writer process is running. In this pid namespace: its pidfd (see
    /// `reader/liveness.rs`). A writer in another pid namespace (`writer_pid_ns`, minor 3)
    /// cannot be looked up by pid: it counts as running while its heartbeat is younger than
    /// [`FOREIGN_WRITER_SILENCE`] plus two chunk periods (bassd refreshes it at least every 80 ms, also
    /// while its device is silent). `now` gives CLOCK_MONOTONIC (ns), read only for such a
    /// writer (the pidfd path needs no clock).
    pub(crate) fn writer_alive(&self, now: impl FnOnce() -> u64) -> bool {
        let h = self.header();
        let ns = h.writer_pid_ns.load(Relaxed);
        if ns != 0 && sys::own_pid_ns().is_some_and(|own| own != ns) {
            let silence = FOREIGN_WRITER_SILENCE.as_nanos() as u64 + 2 * self.geometry.chunk_ns();
            return now().saturating_sub(h.heartbeat_mono_ns.load(Relaxed)) < silence;
        }
        self.watch.alive(h.writer_pid.load(Relaxed), h.writer_start_time.load(Relaxed))
    }

    /// The writer's pid if it is gone for good: its process has ended and no successor can
    /// take the port back any more. A port whose writer left it to a successor (a broker
    /// restarted by its service manager: `restart_grace_ms` in the header, minor 2) keeps
    /// its readers waiting for `restart_grace_ms` after the last heartbeat; a successor that
    /// takes it back continues the same frames. `now` is CLOCK_MONOTONIC (ns).
    pub(crate) fn writer_gone(&self, now: u64) -> Option<u32> {
        let h = self.header();
        let pid = h.writer_pid.load(Relaxed);
        if self.writer_alive(|| now) {
            return None;
        }
        let grace_ms = h.restart_grace_ms.load(Relaxed).min(format::MAX_RESTART_GRACE_MS);
        let grace_ns = u64::from(grace_ms) * 1_000_000;
        let beat = h.heartbeat_mono_ns.load(Relaxed);
        if grace_ns > 0 && now.saturating_sub(beat) < grace_ns {
            return None;
        }
        // A successor that took over while we looked is not gone.
        (h.writer_pid.load(Acquire) == pid).then_some(pid)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_child_is_alive_until_it_ends_then_dead_for_good() {
        let mut child = std::process::Command::new("sleep").arg("30").spawn().unwrap();
        let pid = child.id();
        let start = sys::process_start(pid).unwrap().0;
        let w = WriterWatch::default();
        assert!(w.alive(pid, start));
        assert!(matches!(w.cached.lock().unwrap().as_ref(), Some((_, _, Known::Watched(_)))));
        assert!(w.alive(pid, start), "asked again: the pidfd answers");
        child.kill().unwrap();
        // Killed but not reaped (a zombie): ended for the pidfd, and for /proc.
        let t0 = std::time::Instant::now();
        while w.alive(pid, start) {
            assert!(t0.elapsed() < std::time::Duration::from_secs(10), "still alive after kill");
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        child.wait().unwrap();
        assert!(!w.alive(pid, start));
        assert!(matches!(w.cached.lock().unwrap().as_ref(), Some((_, _, Known::Dead))));
    }

    #[test]
    fn a_pid_with_another_start_time_is_not_the_writer() {
        let me = std::process::id();
        let start = sys::own_start_time();
        let w = WriterWatch::default();
        assert!(w.alive(me, start));
        assert!(!w.alive(me, start + 1), "a recycled pid (other start time) is not the writer");
        assert!(w.alive(me, start), "the real writer is asked about afresh");
        assert!(!w.alive(0, 0));
        assert!(!w.alive(u32::MAX, 1));
    }
}
