//! Waking a port's readers at a cost to the writer that does not grow with their number.
//!
//! `FUTEX_WAKE` costs its caller about 1–3 µs per process it wakes, and the caller is the
//! capture thread. So the writer wakes every reader itself only while the last wake woke at
//! most [`DIRECT_ALL_MAX`] of them (the usual one to a handful of readers get no hop through
//! another thread). With more, the writer hands wakes to a helper thread: it ORs the chunk's
//! futex bits into a pending word and, only when that word was empty, wakes the helper (one
//! futex wake of one thread of its own process, the cost of waking a single reader); the
//! helper issues the `FUTEX_WAKE_BITSET` on the port's futex word for all pending bits.
//!
//! How much it hands over depends on how many wait. Up to [`HAND_ALL_MIN`] readers the writer
//! first wakes [`SPLIT_DIRECT`] of them itself, so that the first readers have no hop: at 16
//! readers waking all through the helper made each reader's wake 1.18–1.52× a raw futex's
//! against 1.05–1.19× with the two direct wakes. Above it the writer wakes none itself: with
//! that many readers on few cores each waits for the CPU time of those woken before it, the
//! hop is lost in that (32 and 64 readers measured the same both ways), and the capture
//! thread pays one wake per chunk however many read (64 readers 0.79–1.09× one reader,
//! against 1.45–1.75× with the two direct wakes). The writer goes back to waking everyone
//! itself once a wake found at most [`DIRECT_ALL_MAX`] readers. docs/performance.md (part 2,
//! part 3 and the analysis) has the measurements.
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

/// With more readers than that, up to this many, the writer wakes this many itself before it
/// hands the rest to the helper.
pub(crate) const SPLIT_DIRECT: u32 = 2;

/// With more readers than this the writer hands every wake to the helper.
pub(crate) const HAND_ALL_MIN: u32 = 32;

/// Wakes the readers of one port (owned by its writer).
pub struct Waker {
    mapping: Arc<Mapping>,
    direct: bool,
    helper: Option<Helper>,
    /// Readers the writer woke itself, over the waker's life (for tests and the benchmark).
    woken_by_writer: u64,
    /// Readers the writer woke itself in its last handed-over wake (0 or [`SPLIT_DIRECT`]).
    split_part: u32,
}

struct Helper {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

/// What the writer and the helper thread share.
struct Shared {
    /// Futex bits published but not yet woken by the helper; also the helper's futex word.
    pending: AtomicU32,
    /// How many readers the helper's last wake woke.
    last_woken: AtomicU32,
    /// Tells the helper to exit.
    stop: AtomicBool,
}

impl Waker {
    /// A waker for the port mapped by `mapping` (wakes directly until readers pile up).
    pub fn new(mapping: Arc<Mapping>) -> Waker {
        Waker { mapping, direct: true, helper: None, woken_by_writer: 0, split_part: 0 }
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
        let futex = &self.mapping.header().futex;
        if self.direct {
            let woken = sys::futex_wake_bits(futex, bits);
            self.woken_by_writer += u64::from(woken);
            if woken > DIRECT_ALL_MAX && self.ensure_helper() {
                self.direct = false;
                self.split_part = 0;
                if let Some(h) = &self.helper {
                    h.shared.last_woken.store(woken, Ordering::Relaxed);
                }
            }
            return;
        }
        let Some(helper) = &self.helper else {
            self.direct = true;
            return self.wake(bits);
        };
        let shared = &helper.shared;
        // How many the last handed-over wake found: the writer's part and the helper's last
        // count (a count of a few publishes ago if the helper lags: it only picks the mode).
        let last = self.split_part + shared.last_woken.load(Ordering::Relaxed);
        if last <= DIRECT_ALL_MAX {
            // Few readers left: the writer alone is enough again (from this publish on).
            self.direct = true;
            return self.wake(bits);
        }
        self.split_part = 0;
        if last <= HAND_ALL_MIN {
            // The first readers straight away; the helper wakes the rest, if there may be more.
            let n = sys::futex_wake_bits_n(futex, bits, SPLIT_DIRECT);
            self.woken_by_writer += u64::from(n);
            if n < SPLIT_DIRECT {
                // Nobody else waited.
                self.direct = true;
                return;
            }
            self.split_part = n;
        }
        if shared.pending.fetch_or(bits, Ordering::Release) == 0 {
            sys::futex_wake_bits(&shared.pending, u32::MAX);
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
            last_woken: AtomicU32::new(0),
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
            shared.last_woken.store(sys::futex_wake_bits(futex, bits), Ordering::Relaxed);
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
