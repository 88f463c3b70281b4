//! The callback stream's steady path is allocation-free: a counting global allocator counts
//! every allocation, reallocation and free made on the stream's thread while a block is due,
//! over 10^5 callbacks of a live writer (with the laps a free-running writer causes), and
//! separately across a device error and its event. Its own test binary: the allocator is
//! global. The counts are per thread: each test runs its stream on its own thread.

use bass_test_support::client as common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use basskit::testsignal::{fill_pattern_interleaved, pattern_expected};
use bassport::format::error_code;
use bassport::stream::{Config, Control, Event, SampleLayout, Start, Stream};
use bassport::{ChunkMeta, Geometry, PortParams, Source, State, Writer};

struct Counting;

thread_local! {
    /// Whether this thread's allocations are counted now.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}
thread_local! {
    /// This thread's counted allocations, reallocations and frees.
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn note() {
    if COUNTING.try_with(Cell::get).unwrap_or(false) {
        let _ = ALLOCATIONS.try_with(|a| a.set(a.get() + 1));
    }
}

/// This thread's count since the last call (and a check that the counter counts).
fn take_allocations() -> u64 {
    ALLOCATIONS.with(|a| a.replace(0))
}

/// The counter sees an allocation and its free (a counter that counts nothing proves nothing).
fn check_the_counter() {
    take_allocations();
    count(true);
    drop(std::hint::black_box(Box::new(7u64)));
    count(false);
    assert_eq!(take_allocations(), 2, "the counting allocator counts an allocation and its free");
}

// SAFETY: every call is forwarded unchanged to the system allocator; counting touches only
// a const-initialised thread-local and an atomic (neither allocates).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: forwarded caller guarantee.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: forwarded caller guarantee.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        note();
        // SAFETY: forwarded caller guarantee.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        // SAFETY: forwarded caller guarantee.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn count(on: bool) {
    COUNTING.with(|c| c.set(on));
}

const CALLBACKS: u64 = 100_000;

fn writer(tag: &str) -> (std::path::PathBuf, Writer) {
    let path = common::temp_port_path(tag);
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 32, chunks_on_port: 16 };
    let w = Writer::create_at(&path, &PortParams { geometry, device: "rt".into(), group: None }).unwrap();
    (path, w)
}

/// Publishes pattern chunks until `done`, then ends the acquisition with `end`.
fn run_writer(mut w: Writer, done: Arc<AtomicBool>, end: impl FnOnce(&Writer)) -> Writer {
    let mut chunk = vec![0; 64];
    let mut i = 0u64;
    while !done.load(Ordering::Acquire) {
        fill_pattern_interleaved(&mut chunk, 2, w.last_frame_index() + 1);
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
        i += 1;
        if i % 8 == 0 {
            std::thread::yield_now();
        }
    }
    end(&w);
    w
}

#[test]
fn the_steady_path_makes_no_allocation_in_100000_callbacks() {
    check_the_counter();
    let (_path, w) = writer("rt-steady");
    let port = Arc::new(bassport::Port::open_path(w.path()).unwrap());
    let mut stream = Stream::new(port, Config { start: Start::Frame(1), ..Config::default() }).unwrap();
    let done = Arc::new(AtomicBool::new(false));
    let d = done.clone();
    let writer = std::thread::spawn(move || run_writer(w, d, |w| w.stop()));
    let (mut calls, mut next, mut delivered, mut lost, mut wrong) = (0u64, 1u64, 0u64, 0u64, 0u64);
    let mut stopped_at = 0;
    stream
        .run(
            |b| {
                count(true); // from the first callback on: the stream is in its steady state
                calls += 1;
                if b.first_frame != next + b.lost {
                    wrong += 1;
                }
                for i in 0..b.frames {
                    let f = b.first_frame + i as u64;
                    wrong += u64::from(b.sample(0, i) != pattern_expected(f, 0));
                    wrong += u64::from(b.sample(1, i) != pattern_expected(f, 1));
                }
                next = b.first_frame + b.frames as u64;
                delivered += b.frames as u64;
                lost += b.lost;
                if calls == CALLBACKS {
                    done.store(true, Ordering::Release);
                }
                Control::Continue
            },
            |e| {
                count(false);
                if let Event::Stopped { last } = *e {
                    stopped_at = last;
                }
                Control::Stop
            },
        )
        .unwrap();
    count(false);
    let allocations = take_allocations();
    let w = writer.join().unwrap();
    assert!(calls >= CALLBACKS, "{calls} callbacks");
    assert_eq!(wrong, 0, "blocks out of place or samples not the pattern's");
    assert_eq!(1 + delivered + lost, stopped_at + 1, "every frame delivered or counted lost");
    assert_eq!(
        allocations, 0,
        "allocations on the stream's thread in {calls} callbacks ({lost} frames lost)"
    );
    eprintln!("{calls} callbacks, {delivered} frames delivered, {lost} lost, {allocations} allocations");
    w.remove().unwrap();
}

#[test]
fn a_device_error_reaches_the_callback_without_an_allocation() {
    check_the_counter();
    let (_path, w) = writer("rt-device");
    let cfg = Config {
        channels: vec![1],
        layout: SampleLayout::Interleaved,
        frames_per_call: 48,
        ..Config::default()
    };
    let mut stream = Stream::open_path(w.path(), cfg).unwrap();
    let done = Arc::new(AtomicBool::new(false));
    let d = done.clone();
    let writer = std::thread::spawn(move || {
        run_writer(w, d, |w| w.set_state(State::Error, error_code::DEVICE_STALLED, "no data for 2 s"))
    });
    let (mut calls, mut device) = (0u64, false);
    stream
        .run(
            |b| {
                count(true);
                calls += 1;
                if calls == 20_000 {
                    done.store(true, Ordering::Release);
                }
                assert_eq!(b.interleaved().map(<[i32]>::len), Some(b.frames));
                Control::Continue
            },
            |e| {
                // The event is built and delivered while still counted; the comparison
                // allocates nothing.
                device = *e == Event::Device { code: error_code::DEVICE_STALLED, message: "no data for 2 s" };
                count(false);
                Control::Stop
            },
        )
        .unwrap();
    count(false);
    assert!(device, "the device error was reported with its code and message");
    assert_eq!(take_allocations(), 0, "allocations across {calls} callbacks and a device error");
    writer.join().unwrap().remove().unwrap();
}
