//! Thin, checked wrappers over the Linux calls bass needs: futex, clocks, process liveness
//! (through rustix, no `unsafe`), and in [`sched`] and [`peer`] the calls rustix does not
//! wrap (libc, each `unsafe` block with its SAFETY comment).

#[allow(unsafe_code)] // libc's getsockopt (SO_PEERCRED)
pub mod peer;
#[allow(unsafe_code)] // libc's sched_getscheduler, sched_getparam, sched_setscheduler
pub mod sched;

use std::num::NonZeroU32;
use std::sync::atomic::AtomicU32;
use std::time::Duration;

use rustix::io::Errno;
use rustix::thread::futex::{self, Timespec};
use rustix::time::ClockId;

/// Outcome of a futex wait.
#[derive(Debug, PartialEq, Eq)]
pub enum FutexWait {
    /// Woken, or the word already differed from the expected value.
    Woken,
    /// The timeout expired.
    TimedOut,
    /// A signal interrupted the wait.
    Interrupted,
}

/// Waits while `*word == expected`, at most `timeout`. Works on a read-only shared mapping
/// (the kernel only reads the word for FUTEX_WAIT), across processes (no FUTEX_PRIVATE_FLAG).
pub fn futex_wait(word: &AtomicU32, expected: u32, timeout: Duration) -> FutexWait {
    // All bits: woken by every FUTEX_WAKE and FUTEX_WAKE_BITSET on the word.
    futex_wait_bits(word, expected, timeout, u32::MAX)
}

/// The futex bit of chunk `chunk` (0-based): waiters for a frame of that chunk wait on it,
/// its publish wakes it (FUTEX_WAIT_BITSET / FUTEX_WAKE_BITSET). 31 bits: a waiter sees at
/// most one spurious wake-up every 31 chunks. Plain FUTEX_WAIT/FUTEX_WAKE match every bit.
pub fn chunk_bit(chunk: u64) -> u32 {
    1 << (chunk % 31)
}

/// The futex bit no chunk's publish uses (chunks use bits 0 to 30): a waiter for a chunk
/// [`FAR_CHUNKS`] or more ahead sleeps on it, since the bit of its own chunk would wake it
/// every 31 chunks. Every state change wakes it (all bits), and so does a writer that runs
/// ahead of real time (see `writer/lead.rs`); otherwise the far waiter sleeps by the port's
/// nominal rate until its chunk is [`FAR_MARGIN`] chunks away, then on its chunk's bit.
pub const FAR_BIT: u32 = 1 << 31;

/// Chunks ahead (target chunk minus the next one to be published) from which a waiter
/// sleeps on [`FAR_BIT`]; nearer, its chunk's bit is woken by no other chunk's publish before
/// its own.
pub const FAR_CHUNKS: u64 = 31;

/// How many chunk periods before its chunk is due, by the port's nominal rate, a far waiter
/// moves to its chunk's own bit. A writer wakes [`FAR_BIT`] once it has gained 16 chunks on
/// real time (one publish later: 17), so a far waiter is never asleep on it when its chunk
/// comes.
pub const FAR_MARGIN: u64 = 20;

/// What a waiter for chunk `target` sleeps on while chunk `next` is the next to be published,
/// `chunk_ns` apart by the port's nominal rate: its chunk's bit, or [`FAR_BIT`] and how long
/// it may sleep on it (ns).
pub fn wait_bits(target: u64, next: u64, chunk_ns: u64) -> (u32, Option<u64>) {
    let ahead = target.saturating_sub(next);
    if ahead < FAR_CHUNKS {
        (chunk_bit(target), None)
    } else {
        (FAR_BIT, Some((ahead - FAR_MARGIN).saturating_mul(chunk_ns)))
    }
}

/// Like [`futex_wait`], but only woken by wakes whose bits intersect `bits` (0 waits for
/// nothing and returns at once).
pub fn futex_wait_bits(word: &AtomicU32, expected: u32, timeout: Duration, bits: u32) -> FutexWait {
    let deadline = monotonic_ns().saturating_add(u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX));
    futex_wait_bits_until(word, expected, deadline, bits)
}

/// Like [`futex_wait_bits`], with an absolute CLOCK_MONOTONIC deadline in nanoseconds (what
/// FUTEX_WAIT_BITSET takes: no clock read here).
pub fn futex_wait_bits_until(word: &AtomicU32, expected: u32, deadline: u64, bits: u32) -> FutexWait {
    let Some(bits) = NonZeroU32::new(bits) else { return FutexWait::Woken };
    let ts = Timespec {
        tv_sec: (deadline / 1_000_000_000).min(i64::MAX as u64) as i64,
        tv_nsec: (deadline % 1_000_000_000) as _,
    };
    // Flags::empty(): a shared futex (no FUTEX_PRIVATE_FLAG), keyed on the mapped page, so
    // it works across processes and on a read-only mapping (the kernel only reads the word).
    match futex::wait_bitset(word, futex::Flags::empty(), expected, Some(&ts), bits) {
        Ok(()) => FutexWait::Woken,
        Err(Errno::TIMEDOUT) => FutexWait::TimedOut,
        Err(Errno::INTR) => FutexWait::Interrupted,
        // EAGAIN: the value already changed.
        Err(_) => FutexWait::Woken,
    }
}

/// Wakes the processes waiting on `word` whose bits intersect `bits`.
pub fn futex_wake_bits(word: &AtomicU32, bits: u32) -> u32 {
    futex_wake_bits_n(word, bits, u32::MAX)
}

/// Wakes at most `n` of the processes waiting on `word` for any of `bits`; returns how many
/// it woke.
pub fn futex_wake_bits_n(word: &AtomicU32, bits: u32, n: u32) -> u32 {
    let Some(bits) = NonZeroU32::new(bits) else { return 0 };
    let woken = futex::wake_bitset(word, futex::Flags::empty(), n.min(i32::MAX as u32), bits);
    // The number of processes woken (an error, impossible with these arguments, counts as 0).
    woken.map_or(0, |n| u32::try_from(n).unwrap_or(u32::MAX))
}

/// Wakes every process waiting on `word`.
pub fn futex_wake_all(word: &AtomicU32) {
    let _ = futex::wake(word, futex::Flags::empty(), i32::MAX as u32);
}

fn clock_ns(clock: ClockId) -> u64 {
    let ts = rustix::time::clock_gettime(clock);
    (ts.tv_sec as u64).wrapping_mul(1_000_000_000).wrapping_add(ts.tv_nsec as u64)
}

/// CLOCK_MONOTONIC in nanoseconds.
pub fn monotonic_ns() -> u64 {
    clock_ns(ClockId::Monotonic)
}

/// CLOCK_REALTIME in nanoseconds.
pub fn realtime_ns() -> u64 {
    clock_ns(ClockId::Realtime)
}

/// Start time (clock ticks after boot) and state letter of process `pid`, from /proc.
pub fn process_start(pid: u32) -> Option<(u64, char)> {
    stat_start(&format!("/proc/{pid}/stat"))
}

/// Start time and state from a `/proc/.../stat` file.
fn stat_start(path: &str) -> Option<(u64, char)> {
    let stat = std::fs::read_to_string(path).ok()?;
    // The command name may contain spaces and parentheses: parse after the last ')'.
    let rest = &stat[stat.rfind(')')? + 1..];
    let mut fields = rest.split_whitespace();
    let state = fields.next()?.chars().next()?;
    // Field 3 is the state; field 22 is the start time: 19 fields after the state.
    let start = fields.nth(18)?.parse().ok()?;
    Some((start, state))
}

/// This process's start time, for the port header. Read from `/proc/self`: in a pid
/// namespace of its own whose /proc is its parent's, `/proc/<getpid()>` is another process.
pub fn own_start_time() -> u64 {
    stat_start("/proc/self/stat").map(|(s, _)| s).unwrap_or(0)
}

/// This process's pid namespace: the inode number of `/proc/self/ns/pid` (None where it
/// cannot be read). Asked once per process.
pub fn own_pid_ns() -> Option<u64> {
    static NS: std::sync::OnceLock<Option<u64>> = std::sync::OnceLock::new();
    *NS.get_or_init(|| rustix::fs::stat("/proc/self/ns/pid").ok().map(|st| st.st_ino))
}

/// Whether the writer `pid` that started at `start_time` is still running.
///
/// A pid that does not exist, a zombie, or a pid recycled by another process
/// (different start time) all count as gone. Where /proc has no entry for the pid,
/// `kill(pid, 0)` decides. The pid must be of this pid namespace (`Port::writer_alive`
/// handles a writer of another one by its heartbeat).
pub fn writer_alive(pid: u32, start_time: u64) -> bool {
    if pid == 0 || pid > i32::MAX as u32 {
        return false;
    }
    match process_start(pid) {
        Some((start, state)) => state != 'Z' && state != 'X' && (start_time == 0 || start == start_time),
        None => match rustix::process::Pid::from_raw(pid as i32) {
            // kill(pid, 0): exists (EPERM: exists, but is another user's).
            Some(p) => matches!(rustix::process::test_kill_process(p), Ok(()) | Err(Errno::PERM)),
            None => false,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_near_waiter_sleeps_on_a_bit_no_earlier_chunk_wakes_and_a_far_one_on_the_far_bit() {
        for next in [0u64, 5, 1_000_000] {
            for ahead in 0..FAR_CHUNKS {
                let target = next + ahead;
                let (bits, far) = wait_bits(target, next, 1000);
                assert_eq!((bits, far), (chunk_bit(target), None));
                assert!((next..target).all(|c| chunk_bit(c) & bits == 0), "chunk {target} from {next}");
                assert_eq!(bits & FAR_BIT, 0);
            }
            assert_eq!(wait_bits(next + 31, next, 1000), (FAR_BIT, Some(11 * 1000)));
            assert_eq!(wait_bits(next + 1500, next, 666_666), (FAR_BIT, Some(1480 * 666_666)));
        }
        // Already published (a frame behind the newest): its own bit, no far sleep.
        assert_eq!(wait_bits(3, 10, 1000), (chunk_bit(3), None));
        assert_eq!(wait_bits(u64::MAX, 0, u64::MAX), (FAR_BIT, Some(u64::MAX)));
    }
}
