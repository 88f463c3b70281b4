//! How long serve's threads wait for the network and for each other: the wait for room in a
//! queue (the backlog's, and the live stream's), and the bounded join of a thread that may be
//! blocked on a dead link (the Zenoh sender, the ROS 2 exporter).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{SyncSender, TrySendError};
use std::time::{Duration, Instant};

/// Longest wait for room in the queue while the backlog goes out. A network that takes longer
/// (a dead link) ends the catch-up: from then on chunks are dropped and counted as usual, and
/// the port lapping serve meanwhile is counted as loss.
pub const CATCH_UP_PATIENCE: Duration = Duration::from_secs(1);

/// How far behind the port's newest frame a live chunk may fall while it waits for room in a
/// queue, at most (and at most half the port's window, [`live_patience_frames`]). The port
/// holds the frames meanwhile, so a stall of serve itself or of the network shorter than this
/// loses nothing: after it the chunks go out as fast as the network takes them. A network
/// that takes less than the stream for longer keeps the stream about this far behind and
/// drops (counted) what falls further back: the lag stays bounded, and it is the oldest
/// chunks that go.
pub const LIVE_PATIENCE: Duration = Duration::from_millis(250);

/// [`LIVE_PATIENCE`] in frames of a port of `sample_rate` holding `frames_on_port` frames.
pub fn live_patience_frames(sample_rate: u32, frames_on_port: u64) -> u64 {
    let frames = u64::from(sample_rate) * LIVE_PATIENCE.as_millis() as u64 / 1000;
    frames.min(frames_on_port / 2)
}

/// Sends `item` on `tx`; while the queue is full, tries again every 200 µs for as long as
/// `may_wait()` says so and `term` is not set. The item comes back if it was not sent.
pub(crate) fn send_or_give_back<T>(
    tx: &SyncSender<T>,
    mut item: T,
    term: &AtomicBool,
    mut may_wait: impl FnMut() -> bool,
) -> Result<(), TrySendError<T>> {
    loop {
        match tx.try_send(item) {
            Err(TrySendError::Full(back)) if !term.load(Ordering::Relaxed) && may_wait() => {
                item = back;
                std::thread::sleep(Duration::from_micros(200));
            }
            other => return other,
        }
    }
}

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
