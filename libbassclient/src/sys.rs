//! Thin, checked wrappers over the Linux calls bass needs: futex, clocks, process liveness.

use std::sync::atomic::AtomicU32;
use std::time::Duration;

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

/// Like [`futex_wait`], but only woken by wakes whose bits intersect `bits`.
pub fn futex_wait_bits(word: &AtomicU32, expected: u32, timeout: Duration, bits: u32) -> FutexWait {
    // FUTEX_WAIT_BITSET takes an absolute CLOCK_MONOTONIC deadline.
    let deadline = monotonic_ns().saturating_add(u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX));
    let ts = libc::timespec {
        tv_sec: (deadline / 1_000_000_000).min(i64::MAX as u64) as libc::time_t,
        tv_nsec: (deadline % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: `word` is a valid, aligned u32 for the duration of the call; the kernel only
    // reads it for FUTEX_WAIT_BITSET; `ts` outlives the call; `bits` is non-zero by
    // construction of the callers; the unused argument is null.
    let r = unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            libc::FUTEX_WAIT_BITSET,
            expected,
            &ts as *const libc::timespec,
            std::ptr::null::<u32>(),
            bits,
        )
    };
    if r == 0 {
        return FutexWait::Woken;
    }
    match std::io::Error::last_os_error().raw_os_error() {
        Some(libc::ETIMEDOUT) => FutexWait::TimedOut,
        Some(libc::EINTR) => FutexWait::Interrupted,
        // EAGAIN: the value already changed.
        _ => FutexWait::Woken,
    }
}

/// Wakes the processes waiting on `word` whose bits intersect `bits`.
pub fn futex_wake_bits(word: &AtomicU32, bits: u32) -> u32 {
    // SAFETY: as in `futex_wake_all`.
    let r = unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            libc::FUTEX_WAKE_BITSET,
            i32::MAX,
            std::ptr::null::<libc::timespec>(),
            std::ptr::null::<u32>(),
            bits,
        )
    };
    // The number of processes woken (an error, impossible with these arguments, counts as 0).
    u32::try_from(r).unwrap_or(0)
}

/// Wakes every process waiting on `word`.
pub fn futex_wake_all(word: &AtomicU32) {
    // SAFETY: `word` is a valid, aligned u32 in a shared mapping; FUTEX_WAKE does not
    // access memory beyond computing the futex key.
    unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            libc::FUTEX_WAKE,
            i32::MAX,
            std::ptr::null::<libc::timespec>(),
            std::ptr::null::<u32>(),
            0u32,
        );
    }
}

fn clock_ns(clock: libc::clockid_t) -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid out-pointer; the clock ids used here always exist on Linux.
    unsafe { libc::clock_gettime(clock, &mut ts) };
    (ts.tv_sec as u64).wrapping_mul(1_000_000_000).wrapping_add(ts.tv_nsec as u64)
}

/// CLOCK_MONOTONIC in nanoseconds.
pub fn monotonic_ns() -> u64 {
    clock_ns(libc::CLOCK_MONOTONIC)
}

/// CLOCK_REALTIME in nanoseconds.
pub fn realtime_ns() -> u64 {
    clock_ns(libc::CLOCK_REALTIME)
}

/// Start time (clock ticks after boot) and state letter of process `pid`, from /proc.
pub fn process_start(pid: u32) -> Option<(u64, char)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name may contain spaces and parentheses: parse after the last ')'.
    let rest = &stat[stat.rfind(')')? + 1..];
    let mut fields = rest.split_whitespace();
    let state = fields.next()?.chars().next()?;
    // Field 3 is the state; field 22 is the start time: 19 fields after the state.
    let start = fields.nth(18)?.parse().ok()?;
    Some((start, state))
}

/// This process's start time, for the port header.
pub fn own_start_time() -> u64 {
    process_start(std::process::id()).map(|(s, _)| s).unwrap_or(0)
}

/// Whether the writer `pid` that started at `start_time` is still running.
///
/// A pid that does not exist, a zombie, or a pid recycled by another process
/// (different start time) all count as gone. Where /proc cannot tell (another pid
/// namespace), `kill(pid, 0)` decides.
pub fn writer_alive(pid: u32, start_time: u64) -> bool {
    if pid == 0 || pid > i32::MAX as u32 {
        return false;
    }
    match process_start(pid) {
        Some((start, state)) => state != 'Z' && state != 'X' && (start_time == 0 || start == start_time),
        None => {
            // SAFETY: kill with signal 0 only checks for existence and permission.
            let r = unsafe { libc::kill(pid as libc::pid_t, 0) };
            r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
        }
    }
}
