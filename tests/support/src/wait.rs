//! Bounded waits: poll a condition until it holds or a generous deadline passes.

use std::time::{Duration, Instant};

/// Generous bound for anything that should happen "soon" (never a pass/fail on timing: only
/// a guard against hanging forever).
pub const PATIENCE: Duration = Duration::from_secs(20);

/// Polls `f` every 10 ms until it returns `Some`; panics naming `what` after [`PATIENCE`].
pub fn eventually<T>(what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + PATIENCE;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "gave up waiting for {what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Polls `cond` every millisecond until it holds or `timeout` passes; returns whether it held.
pub fn wait_until(timeout: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + timeout;
    loop {
        if cond() {
            return true;
        }
        if Instant::now() >= end {
            return false;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}
