//! A stream on a thread of its own: the handle that stops and joins it.

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
