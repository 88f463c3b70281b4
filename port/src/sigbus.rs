//! A guard against SIGBUS from port files that shrink under a reader's (or the writer's)
//! mapping.
//!
//! A port *file* can be shrunk by its owner or root while readers have it mapped; touching a
//! mapped page that now lies past the end of the file raises SIGBUS, which kills the reader
//! (or the broker, for its own writable mapping).
//! A per-call size check narrows that window but cannot close it (the file can shrink between
//! the check and the access), and it costs a system call on every call — the first after a
//! wake-up is the dearest (several µs in a virtual machine).
//!
//! This module closes the window the way Wayland compositors guard client shared memory: a
//! process-wide SIGBUS handler, installed the first time a port file is mapped, looks the
//! faulting address up in a fixed table of registered port mappings. If it lies in one, the
//! handler marks that mapping *broken* and maps anonymous zero pages over the whole of it
//! (`MAP_FIXED`), so the faulting load re-executes and reads zero; the library checks the
//! broken mark after its accesses and reports [`crate::Error::Corrupt`] instead of the data
//! (a writer's mapping gets writable zero pages, and its next publish fails the same way).
//! Any other SIGBUS goes to the handler that was installed before (or, if that was the
//! default action, kills the process as it would have).
//!
//! The handler only does async-signal-safe work: atomic loads and stores on a static table
//! and one `mmap` system call. The table has [`SLOTS`] entries; a mapping that finds none
//! free, or a process that sets `BASS_SIGBUS_GUARD=0` (a host that must own SIGBUS itself),
//! is not guarded, and its reader falls back to checking the size before every access.

use std::ffi::c_void;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::OnceLock;

/// How many port mappings one process can have guarded at once.
pub const SLOTS: usize = 256;

struct Slot {
    /// Claimed by a registered mapping.
    used: AtomicBool,
    start: AtomicUsize,
    len: AtomicUsize,
    /// Mapped writable (the writer's mapping): the zero pages are writable too.
    writable: AtomicBool,
    /// Set by the handler when it replaced the mapping with zero pages.
    broken: AtomicBool,
}

#[allow(clippy::declare_interior_mutable_const)] // only used to initialise TABLE
const EMPTY: Slot = Slot {
    used: AtomicBool::new(false),
    start: AtomicUsize::new(0),
    len: AtomicUsize::new(0),
    writable: AtomicBool::new(false),
    broken: AtomicBool::new(false),
};

static TABLE: [Slot; SLOTS] = [EMPTY; SLOTS];

/// The SIGBUS disposition found when the handler was installed (None: not installed).
static PREVIOUS: OnceLock<Option<Previous>> = OnceLock::new();

/// The earlier SIGBUS action, kept to pass on faults that are not ours.
struct Previous(libc::sigaction);

// SAFETY: a `sigaction` is plain data (a handler address, flags and a signal mask); it is
// written once, before it is published through the OnceLock, and only read afterwards.
unsafe impl Send for Previous {}
// SAFETY: as above: never mutated after publication.
unsafe impl Sync for Previous {}

/// A registered port mapping; unregisters on drop (drop it before unmapping).
pub struct Guard {
    slot: usize,
}

impl Guard {
    /// Guards the mapping at `ptr` (`len` bytes, mapped `PROT_READ`, and `PROT_WRITE` if
    /// `writable`: the writer keeps writing, into zero pages nobody else sees, until it
    /// checks [`Guard::broken`]). None when the guard is
    /// off (`BASS_SIGBUS_GUARD=0`), the handler could not be installed or has since been
    /// replaced by another (a host that installs its own SIGBUS handler after bass), or all
    /// slots are used: the caller then checks the file's size itself.
    pub fn register(ptr: *const u8, len: usize, writable: bool) -> Option<Guard> {
        if len == 0 || !installed() || !still_ours() {
            return None;
        }
        let slot = TABLE.iter().position(|s| {
            s.used.compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed).is_ok()
        })?;
        let s = &TABLE[slot];
        s.broken.store(false, Ordering::Relaxed);
        s.writable.store(writable, Ordering::Relaxed);
        s.start.store(ptr as usize, Ordering::Relaxed);
        s.len.store(len, Ordering::Release);
        Some(Guard { slot })
    }

    /// Whether a SIGBUS in this mapping replaced it with zero pages (its file shrank): every
    /// value read from it since may be zero instead of the port's.
    pub fn broken(&self) -> bool {
        TABLE[self.slot].broken.load(Ordering::SeqCst)
    }
}

impl Drop for Guard {
    fn drop(&mut self) {
        let s = &TABLE[self.slot];
        s.len.store(0, Ordering::Release);
        s.start.store(0, Ordering::Relaxed);
        s.used.store(false, Ordering::Release);
    }
}

/// Installs the handler once per process; whether it is installed.
fn installed() -> bool {
    PREVIOUS
        .get_or_init(|| {
            if std::env::var_os("BASS_SIGBUS_GUARD").is_some_and(|v| v == "0") {
                return None;
            }
            // SAFETY: zeroed `sigaction` structs are valid (empty masks, null handlers); the
            // new action's handler is a valid `extern "C"` function of the SA_SIGINFO shape;
            // `sigaction` writes the previous action into `old`, a valid out-pointer.
            unsafe {
                let mut new: libc::sigaction = std::mem::zeroed();
                new.sa_sigaction = on_sigbus as *const () as usize;
                new.sa_flags = libc::SA_SIGINFO | libc::SA_ONSTACK;
                libc::sigemptyset(&mut new.sa_mask);
                let mut old: libc::sigaction = std::mem::zeroed();
                (libc::sigaction(libc::SIGBUS, &new, &mut old) == 0).then_some(Previous(old))
            }
        })
        .is_some()
}

/// Whether SIGBUS is still handled by [`on_sigbus`] (checked at every registration, i.e. at
/// every port opened: a handler installed over ours without chaining would leave faults in
/// port mappings unhandled).
fn still_ours() -> bool {
    // SAFETY: a null new action only queries; `cur` is a valid out-pointer.
    unsafe {
        let mut cur: libc::sigaction = std::mem::zeroed();
        libc::sigaction(libc::SIGBUS, std::ptr::null(), &mut cur) == 0
            && cur.sa_sigaction == on_sigbus as *const () as usize
    }
}

/// The SIGBUS handler (async-signal-safe: atomics and `mmap` only).
extern "C" fn on_sigbus(sig: libc::c_int, info: *mut libc::siginfo_t, ctx: *mut c_void) {
    // SAFETY: with SA_SIGINFO the kernel passes a valid siginfo; `si_addr` is the faulting
    // address for a SIGBUS raised by a memory access.
    let (code, addr) = unsafe { ((*info).si_code, (*info).si_addr() as usize) };
    if code == libc::BUS_ADRERR {
        for s in TABLE.iter() {
            let len = s.len.load(Ordering::Acquire);
            let start = s.start.load(Ordering::Relaxed);
            if len == 0 || addr < start || addr - start >= len {
                continue;
            }
            s.broken.store(true, Ordering::SeqCst);
            let prot = if s.writable.load(Ordering::Relaxed) {
                libc::PROT_READ | libc::PROT_WRITE
            } else {
                libc::PROT_READ
            };
            // SAFETY: [start, start + len) is a live mapping of a port registered by this
            // process (a Guard is dropped before its mapping is unmapped); replacing it with
            // private anonymous zero pages, with the protection the mapping had, keeps every
            // reference into it valid, and the faulting access then reads (or writes) zero
            // pages.
            let p = unsafe {
                libc::mmap(
                    start as *mut c_void,
                    len,
                    prot,
                    libc::MAP_PRIVATE | libc::MAP_ANONYMOUS | libc::MAP_FIXED,
                    -1,
                    0,
                )
            };
            if p != libc::MAP_FAILED {
                return;
            }
            break;
        }
    }
    pass_on(sig, info, ctx);
}

/// Hands a SIGBUS that is not ours to the earlier disposition.
fn pass_on(sig: libc::c_int, info: *mut libc::siginfo_t, ctx: *mut c_void) {
    let Some(Some(Previous(old))) = PREVIOUS.get() else { return reset_default(sig) };
    let handler = old.sa_sigaction;
    if handler == libc::SIG_DFL || handler == libc::SIG_IGN {
        // A fault cannot be ignored: the default action, when the access re-executes.
        return reset_default(sig);
    }
    if old.sa_flags & libc::SA_SIGINFO != 0 {
        // SAFETY: the earlier handler was installed with SA_SIGINFO, so it has this shape.
        let f: extern "C" fn(libc::c_int, *mut libc::siginfo_t, *mut c_void) =
            unsafe { std::mem::transmute(handler) };
        f(sig, info, ctx);
    } else {
        // SAFETY: an earlier handler without SA_SIGINFO takes the signal number only.
        let f: extern "C" fn(libc::c_int) = unsafe { std::mem::transmute(handler) };
        f(sig);
    }
}

/// Restores the default action: the faulting access runs again and the process dies of
/// SIGBUS (with a core dump if enabled), as without this module.
fn reset_default(sig: libc::c_int) {
    // SAFETY: a zeroed sigaction is SIG_DFL with an empty mask; `sigaction` is
    // async-signal-safe.
    unsafe {
        let dfl: libc::sigaction = std::mem::zeroed();
        libc::sigaction(sig, &dfl, std::ptr::null_mut());
    }
}
