//! Loom model of the window protocol (`src/ring.rs`, compiled here against loom's atomics).
//!
//! Run with `make test-loom` (RUSTFLAGS="--cfg loom"). One writer publishes frames whose
//! sample encodes the frame index into a 2-frame window while a reader reads; loom explores
//! the interleavings and weak-memory outcomes. The protocol must never deliver a sample
//! that does not belong to its frame, and must account delivered + lost exactly. The
//! known-bad variant (no intent re-check after the copy) must be caught.
#![cfg(loom)]

mod sync {
    pub use loom::sync::atomic;
}

#[allow(dead_code)]
#[path = "../src/ring.rs"]
mod ring;

use loom::sync::atomic::{AtomicU64, Ordering};
use loom::sync::Arc;
use ring::{ReadOutcome, Ring, Source};

const NFOP: u64 = 2;
const FRAMES: u64 = 3;

struct Shared {
    lfi: AtomicU64,
    intent: AtomicU64,
    samples: Vec<AtomicU64>,
}

impl Shared {
    fn ring(&self) -> Ring<'_> {
        Ring {
            last_frame_index: &self.lfi,
            write_intent: &self.intent,
            samples: &self.samples,
            frames_on_port: NFOP,
        }
    }
}

fn value(frame: u64) -> i32 {
    if frame == 0 {
        0
    } else {
        frame as i32 * 10
    }
}

fn model(read: fn(&Ring<'_>, u64, usize, u64, &mut [&mut [i32]]) -> ReadOutcome) -> usize {
    let explored = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let counter = explored.clone();
    loom::model(move || {
        counter.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let shared = Arc::new(Shared {
            lfi: AtomicU64::new(0),
            intent: AtomicU64::new(0),
            samples: (0..NFOP.div_ceil(2)).map(|_| AtomicU64::new(0)).collect(),
        });
        let w = shared.clone();
        let writer = loom::thread::spawn(move || {
            for f in 1..=FRAMES {
                let v = [value(f)];
                // The writer owns the last frame index: it passes it in, as `Writer` does.
                w.ring().publish(f - 1, 1, 1, &Source::Interleaved(&v), || {});
            }
        });
        let ring = shared.ring();
        let lfi = shared.lfi.load(Ordering::Acquire);
        let nfr = 1;
        let mut buf = [i32::MIN; NFOP as usize];
        let r = read(&ring, lfi, NFOP as usize, nfr, &mut [&mut buf[..]]);
        // Accounting: every frame between nfr and the new nfr is either delivered or lost.
        assert_eq!(r.frames as u64 + r.loss, r.next_frame - nfr);
        let first = r.next_frame - r.frames as u64;
        for (i, got) in buf[..r.frames].iter().enumerate() {
            assert_eq!(*got, value(first + i as u64), "frame {} delivered torn", first + i as u64);
        }
        writer.join().unwrap();
    });
    explored.load(std::sync::atomic::Ordering::Relaxed)
}

#[test]
fn reader_never_delivers_a_torn_frame_and_accounts_exactly() {
    let explored = model(|ring, lfi, max, nfr, out| ring.read(lfi, max, nfr, out));
    eprintln!("loom explored {explored} executions");
    // Guards the model itself: a model that explores (almost) nothing proves nothing.
    assert!(explored > 100, "loom explored only {explored} executions");
}

#[test]
#[should_panic(expected = "delivered torn")]
fn model_rejects_a_reader_without_the_recheck() {
    model(|ring, lfi, max, nfr, out| ring.read_without_recheck(lfi, max, nfr, out));
}

/// Frame at which the started model's window begins (`start_at`): frames 1 and 2 never exist.
const START: u64 = 3;

/// A replica window started at `START`: the writer starts it and publishes
/// `START..START + FRAMES` while a reader reads from frame 1. Frames before `START` must
/// never be delivered (they would be zeros presented as audio): only counted as lost.
fn started_model(publish: fn(&Ring<'_>, u64, &[i32])) -> usize {
    let explored = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let counter = explored.clone();
    loom::model(move || {
        counter.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let shared = Arc::new(Shared {
            lfi: AtomicU64::new(0),
            intent: AtomicU64::new(0),
            samples: (0..NFOP.div_ceil(2)).map(|_| AtomicU64::new(0)).collect(),
        });
        let w = shared.clone();
        let writer = loom::thread::spawn(move || {
            w.ring().start_at(START);
            for f in START..START + FRAMES - 1 {
                publish(&w.ring(), f - 1, &[value(f)]);
            }
        });
        let ring = shared.ring();
        let lfi = shared.lfi.load(Ordering::Acquire);
        let nfr = 1;
        let mut buf = [i32::MIN; NFOP as usize];
        let r = ring.read(lfi, NFOP as usize, nfr, &mut [&mut buf[..]]);
        assert_eq!(r.frames as u64 + r.loss, r.next_frame - nfr);
        let first = r.next_frame - r.frames as u64;
        for (i, got) in buf[..r.frames].iter().enumerate() {
            let f = first + i as u64;
            assert!(f >= START, "frame {f}, before the start, delivered as {got}");
            assert_eq!(*got, value(f), "frame {f} delivered torn");
        }
        writer.join().unwrap();
    });
    explored.load(std::sync::atomic::Ordering::Relaxed)
}

#[test]
fn frames_before_a_start_are_never_delivered() {
    let explored = started_model(|ring, lfi, v| {
        ring.publish(lfi, 1, 1, &Source::Interleaved(v), || {});
    });
    eprintln!("loom explored {explored} executions (started window)");
    assert!(explored > 20, "loom explored only {explored} executions");
}

#[test]
#[should_panic(expected = "before the start")]
fn model_rejects_a_publish_that_lowers_the_start_floor() {
    started_model(|ring, lfi, v| {
        ring.publish_without_floor(lfi, 1, 1, &Source::Interleaved(v));
    });
}
