//! How long serve's threads wait for the network and for each other: the catch-up's wait for
//! room in a queue, and the bounded join of a thread that may be blocked on a dead link (the
//! Zenoh sender, the ROS 2 exporter).

use std::time::{Duration, Instant};

/// Longest wait for room in the queue while the backlog goes out. A network that takes longer
/// (a dead link) ends the catch-up: from then on chunks are dropped and counted as usual, and
/// the port lapping serve meanwhile is counted as loss.
pub const CATCH_UP_PATIENCE: Duration = Duration::from_secs(1);

/// Waits up to `patience` for `thread` to finish; whether it did.
pub(crate) fn wait_until_finished<T>(thread: &std::thread::JoinHandle<T>, patience: Duration) -> bool {
    let t0 = Instant::now();
    while !thread.is_finished() {
        if t0.elapsed() >= patience {
            return false;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    true
}
