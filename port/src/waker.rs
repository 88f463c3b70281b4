//! Waking a port's readers at a cost to the writer that does not grow with their number.
//!
//! `FUTEX_WAKE` costs its caller about 1–3 µs per process it wakes, and the caller is the
//! capture thread. So the writer wakes every reader itself only while the last wake woke at
//! most [`DIRECT_ALL_MAX`] of them (the usual one to a handful of readers get no hop through
//! another thread). When a wake woke more, the writer hands the wakes to a helper thread: it
//! ORs the chunk's futex bits into a pending word and, only when that word was empty, wakes
//! the helper (one futex wake of one thread of its own process, the cost of waking a single
//! reader). The helper issues the `FUTEX_WAKE_BITSET` on the port's futex word for all
//! pending bits. The writer goes back to waking everyone itself as soon as the helper's last
//! wake found at most [`DIRECT_ALL_MAX`] readers. So with many readers the capture thread
//! pays one wake per chunk however many wait: 64 readers cost it what one does.
//!
//! Until 2026-12 the writer still woke the first 2 readers itself before the hand-over, so
//! that they had no hop; that made the capture thread pay three wakes per chunk (64 readers
//! 1.45–1.75× one reader) and bought nothing measurable: the 64 readers' wake latency against
//! a raw futex was the same both ways (docs/performance.md, part 2, part 3 and the analysis).
//!
//! The helper is spawned the first time it is needed, from the writer's thread, so it
//! inherits that thread's scheduling class (the capture thread's SCHED_FIFO priority); it is
//! stopped and joined when the writer is dropped.

use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use crate::shm::Mapping;
use crate::sys;

/// The writer wakes everyone itself while the last wake woke at most this many readers.
pub(crate) const DIRECT_ALL_MAX: u32 = 8;

/// Wakes the readers of one port (owned by its writer).
pub struct Waker {
    mapping: Arc<Mapping>,
    direct: bool,
    helper: Option<Helper>,
    /// Readers the writer woke itself, over the waker's life (for tests and the benchmark).
    woken_by_writer: u64,
}

struct Helper {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

/// What the writer and the helper thread share.
struct Shared {
    /// Futex bits published but not yet woken by the helper; also the helper's futex word.
    pending: AtomicU32,
    /// Set when the last wake by the helper woke so few readers that the writer can wake
    /// them all itself again.
    woke_few: AtomicBool,
    /// Tells the helper to exit.
    stop: AtomicBool,
}

impl Waker {
    /// A waker for the port mapped by `mapping` (wakes directly until readers pile up).
    pub fn new(mapping: Arc<Mapping>) -> Waker {
        Waker { mapping, direct: true, helper: None, woken_by_writer: 0 }
    }

    /// How many reader wake-ups the writer made itself (not through the helper) so far.
    pub fn woken_by_writer(&self) -> u64 {
        self.woken_by_writer
    }

    /// Whether the next wake is made by the writer itself (for tests and the benchmark).
    pub fn is_direct(&self) -> bool {
        self.direct
    }

    /// Wakes the readers waiting on `bits` of the port's futex word (after the writer
    /// incremented it).
    pub fn wake(&mut self, bits: u32) {
        if self.direct {
            let woken = sys::futex_wake_bits(&self.mapping.header().futex, bits);
            self.woken_by_writer += u64::from(woken);
            if woken > DIRECT_ALL_MAX && self.ensure_helper() {
                self.direct = false;
            }
            return;
        }
        let Some(helper) = &self.helper else {
            self.direct = true;
            return self.wake(bits);
        };
        // Many readers: the helper wakes them all. The writer wakes the helper only when no
        // earlier hand-over is still pending (the helper takes every pending bit at once).
        let shared = &helper.shared;
        if shared.pending.fetch_or(bits, Ordering::Release) == 0 {
            sys::futex_wake_bits(&shared.pending, u32::MAX);
        }
        // The helper's last wake found few readers: the writer alone is enough again.
        if shared.woke_few.swap(false, Ordering::Relaxed) {
            self.direct = true;
        }
    }

    /// Starts the helper thread if it does not run; false if it cannot be started (then the
    /// writer keeps waking directly: slower with many readers, never wrong).
    fn ensure_helper(&mut self) -> bool {
        if self.helper.is_some() {
            return true;
        }
        let shared = Arc::new(Shared {
            pending: AtomicU32::new(0),
            woke_few: AtomicBool::new(false),
            stop: AtomicBool::new(false),
        });
        let (s, m) = (shared.clone(), self.mapping.clone());
        match std::thread::Builder::new().name("bass-waker".into()).spawn(move || run_helper(&s, &m)) {
            Ok(t) => {
                self.helper = Some(Helper { shared, thread: Some(t) });
                true
            }
            // No thread (resource limits): the writer keeps waking directly.
            Err(_) => false,
        }
    }
}

fn run_helper(shared: &Shared, mapping: &Mapping) {
    let futex = &mapping.header().futex;
    loop {
        if shared.stop.load(Ordering::Acquire) {
            return;
        }
        let bits = shared.pending.swap(0, Ordering::Acquire);
        if bits != 0 {
            if sys::futex_wake_bits(futex, bits) <= DIRECT_ALL_MAX {
                shared.woke_few.store(true, Ordering::Relaxed);
            }
            continue;
        }
        // Returns at once if `pending` is no longer 0; the timeout only bounds a lost wake.
        sys::futex_wait(&shared.pending, 0, Duration::from_secs(1));
    }
}

impl Drop for Waker {
    fn drop(&mut self) {
        if let Some(h) = self.helper.as_mut() {
            h.shared.stop.store(true, Ordering::Release);
            // A non-zero pending word makes a helper about to sleep return at once.
            h.shared.pending.fetch_or(1, Ordering::Release);
            sys::futex_wake_bits(&h.shared.pending, u32::MAX);
            if let Some(t) = h.thread.take() {
                let _ = t.join();
            }
        }
    }
}
