//! Waking a port's readers at a cost to the writer that does not grow with their number.
//!
//! `FUTEX_WAKE` costs its caller about 1 µs per process it wakes, and the caller is the
//! capture thread. So the writer wakes every reader itself only while the last wake woke at
//! most [`DIRECT_MAX`] of them (the common case of one or two readers: no hop through another
//! thread). When a wake woke more, the writer switches to split wakes: it wakes at most
//! [`DIRECT_MAX`] readers itself, straight away, and if that many were waiting hands the rest
//! to a helper thread: it ORs the chunk's futex bits into a pending word and, only when that
//! word was empty, wakes the helper (one process-local futex wake of one thread). The helper
//! issues the `FUTEX_WAKE_BITSET` on the port's futex word for all pending bits. The writer
//! goes back to waking everyone itself as soon as its own wake found fewer than
//! [`DIRECT_MAX`] waiting, or the helper's found none. So the capture thread pays at most
//! [`DIRECT_MAX`] wakes and one hand-over per chunk however many readers wait, and the first
//! readers are woken without the hop (measured in docs/performance.md, part 3: with 8
//! readers the median reader's wake went from 1.5–2.3× to 1.1–1.35× a raw futex waking 8
//! processes, against a full hand-over to the helper).
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

/// The writer wakes everyone itself while the last wake woke at most this many readers, and
/// at most this many itself otherwise.
pub(crate) const DIRECT_MAX: u32 = 2;

/// Wakes the readers of one port (owned by its writer).
pub struct Waker {
    mapping: Arc<Mapping>,
    direct: bool,
    helper: Option<Helper>,
}

struct Helper {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

/// What the writer and the helper thread share.
struct Shared {
    /// Futex bits published but not yet woken by the helper; also the helper's futex word.
    pending: AtomicU32,
    /// Set when the last wake by the helper woke nobody.
    woke_none: AtomicBool,
    /// Tells the helper to exit.
    stop: AtomicBool,
}

impl Waker {
    /// A waker for the port mapped by `mapping` (wakes directly until readers pile up).
    pub fn new(mapping: Arc<Mapping>) -> Waker {
        Waker { mapping, direct: true, helper: None }
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
            if woken > DIRECT_MAX && self.ensure_helper() {
                self.direct = false;
            }
            return;
        }
        let Some(helper) = &self.helper else {
            self.direct = true;
            return self.wake(bits);
        };
        // The first readers straight away; the helper wakes the rest, if there may be more.
        if sys::futex_wake_bits_n(&self.mapping.header().futex, bits, DIRECT_MAX) < DIRECT_MAX {
            // Nobody else waited: the writer alone is enough again.
            self.direct = true;
            return;
        }
        let shared = &helper.shared;
        if shared.pending.fetch_or(bits, Ordering::Release) == 0 {
            sys::futex_wake_bits(&shared.pending, u32::MAX);
        }
        if shared.woke_none.swap(false, Ordering::Relaxed) {
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
            woke_none: AtomicBool::new(false),
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
            if sys::futex_wake_bits(futex, bits) == 0 {
                shared.woke_none.store(true, Ordering::Relaxed);
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
