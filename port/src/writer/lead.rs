//! How far a writer runs ahead of real time, so that far waiters are not left asleep.
//!
//! A reader waiting for a chunk [`sys::FAR_CHUNKS`] or more ahead sleeps on
//! [`sys::FAR_BIT`], which no chunk's publish wakes, until its chunk is [`sys::FAR_MARGIN`]
//! chunk periods away by the port's nominal rate. A writer that publishes faster than that
//! (a replay faster than real time, a replica catching up after an outage, a device burst
//! after a stall) would reach the chunk before the sleep ends. So the writer keeps its lead
//! over real time: a bucket that gains one chunk period per publish and drains with the
//! time between publishes, never below zero (a late writer owes nothing). Each time the lead
//! climbs into a further step of [`STEP_CHUNKS`] chunk periods, the next publish also wakes
//! [`sys::FAR_BIT`]: its far waiters look again. Between two such wakes the lead grows by less
//! than a step plus the one publish of delay (17 chunks), under the far waiters' margin of 20.
//! A writer at its nominal rate, or with ALSA periods of up to 16 chunks, never wakes it.

use crate::sys;

/// The lead, in chunk periods, that makes a step.
const STEP_CHUNKS: u64 = 16;
const _: () = assert!(STEP_CHUNKS + 1 < sys::FAR_MARGIN);

/// A writer's lead over real time.
#[derive(Debug)]
pub(super) struct Lead {
    chunk_ns: u64,
    step_ns: u64,
    lead_ns: u64,
    /// The step the lead was in after the last publish.
    step: u64,
    /// CLOCK_MONOTONIC of the last publish (0: none yet).
    last_ns: u64,
    /// The lead climbed into a further step: the next publish wakes [`sys::FAR_BIT`].
    due: bool,
}

impl Lead {
    pub(super) fn new(chunk_ns: u64) -> Lead {
        let chunk_ns = chunk_ns.max(1);
        Lead { chunk_ns, step_ns: chunk_ns * STEP_CHUNKS, lead_ns: 0, step: 0, last_ns: 0, due: false }
    }

    /// The bits a publish adds to its chunk's: [`sys::FAR_BIT`] once after the lead climbed.
    pub(super) fn take_far_bit(&mut self) -> u32 {
        if std::mem::take(&mut self.due) {
            sys::FAR_BIT
        } else {
            0
        }
    }

    /// A chunk was published at `now_ns` (CLOCK_MONOTONIC).
    pub(super) fn published(&mut self, now_ns: u64) {
        let since = if self.last_ns == 0 { u64::MAX } else { now_ns.saturating_sub(self.last_ns) };
        self.last_ns = now_ns;
        self.lead_ns = (self.lead_ns + self.chunk_ns).saturating_sub(since);
        let step = self.lead_ns / self.step_ns;
        self.due |= step > self.step;
        self.step = step;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CHUNK: u64 = 1_000_000; // 1 ms

    /// Publishes `n` chunks `gap_ns` apart from `*t`; returns how many wake the far bit.
    fn run(lead: &mut Lead, t: &mut u64, n: u64, gap_ns: u64) -> u64 {
        let mut far = 0;
        for _ in 0..n {
            far += u64::from(lead.take_far_bit() != 0);
            *t += gap_ns;
            lead.published(*t);
        }
        far
    }

    #[test]
    fn at_the_nominal_rate_or_late_the_far_bit_is_never_woken() {
        let (mut lead, mut t) = (Lead::new(CHUNK), 5_000_000_000);
        assert_eq!(run(&mut lead, &mut t, 10_000, CHUNK), 0);
        assert_eq!(run(&mut lead, &mut t, 1_000, 3 * CHUNK), 0, "a late writer");
        // Jitter around the rate: 0.3 and 1.7 periods alternately.
        for _ in 0..1_000 {
            assert_eq!(
                run(&mut lead, &mut t, 1, CHUNK * 3 / 10) + run(&mut lead, &mut t, 1, CHUNK * 17 / 10),
                0
            );
        }
    }

    #[test]
    fn periods_of_up_to_16_chunks_published_at_once_never_wake_it() {
        let (mut lead, mut t) = (Lead::new(CHUNK), 1);
        for _ in 0..500 {
            // 16 chunks in one go (1 us apart), then the rest of the 16-chunk period.
            assert_eq!(run(&mut lead, &mut t, 16, 1_000), 0);
            t += 16 * CHUNK - 16_000;
        }
    }

    #[test]
    fn a_writer_ahead_of_real_time_wakes_it_at_least_every_17_chunks_of_lead() {
        let (mut lead, mut t) = (Lead::new(CHUNK), 1);
        run(&mut lead, &mut t, 100, CHUNK);
        // 4x real time: the lead grows 0.75 chunk per publish, a step every ~21 publishes.
        let mut since_far = 0;
        let mut lead_since_far = 0.0;
        let mut wakes = 0;
        for _ in 0..2_000 {
            let far = lead.take_far_bit() != 0;
            if far {
                wakes += 1;
                since_far = 0;
                lead_since_far = 0.0;
            }
            t += CHUNK / 4;
            lead.published(t);
            since_far += 1;
            lead_since_far += 0.75;
            assert!(lead_since_far < 17.0 + 1e-9, "{lead_since_far} chunks of lead without a far wake");
        }
        assert!(since_far < 23);
        assert!((90..=96).contains(&wakes), "{wakes} far wakes in 2000 publishes at 4x");
        // A burst as fast as it goes after the writer fell behind (its lead drained): the far
        // bit goes with the publish after the one that reached 16 chunks of lead.
        run(&mut lead, &mut t, 1, 10_000 * CHUNK);
        let mut n = 0;
        while lead.take_far_bit() == 0 {
            t += 1_000;
            lead.published(t);
            n += 1;
        }
        assert_eq!(n, 17, "publishes before the far wake");
    }

    /// The contract with far waiters, on a real port: a thread asleep on the port's futex
    /// word with [`sys::FAR_BIT`] is not woken by a writer at its nominal rate, and is woken
    /// once the writer has gained 16 chunks of lead running 10x faster (the 19th publish).
    #[test]
    fn a_writer_running_ahead_wakes_a_thread_asleep_on_the_far_bit() {
        use crate::format::Geometry;
        use crate::writer::{ChunkMeta, PortParams, Writer};
        use crate::{Port, Source};
        use std::sync::atomic::Ordering::Acquire;
        use std::time::{Duration, Instant};

        const NFPC: u64 = 480; // 10 ms at 48 kHz
        let dir = std::env::temp_dir().join(format!("bass-lead-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let geometry =
            Geometry { channels: 1, sample_rate: 48_000, frames_per_chunk: NFPC as u32, chunks_on_port: 64 };
        let params = PortParams { geometry, device: "lead-test".into(), group: None };
        let mut w = Writer::create_at(&dir.join("lead.port"), &params).unwrap();
        let chunk = vec![7i32; NFPC as usize];
        let publish = |w: &mut Writer| w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
        publish(&mut w); // the first chunk wakes every bit
        let port = Port::open_path(w.path()).unwrap();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let waiter = std::thread::spawn(move || {
            let futex = &port.stream_header().futex;
            let seq = futex.load(Acquire);
            ready_tx.send(()).unwrap();
            let woken = sys::futex_wait_bits(futex, seq, Duration::from_secs(20), sys::FAR_BIT);
            (woken, port.stream_header().last_frame_index.load(Acquire))
        });
        ready_rx.recv().unwrap();
        std::thread::sleep(Duration::from_millis(50)); // asleep in the kernel by now
                                                       // 30 chunks at the nominal rate, then 200 at 10x (deadlines, so a late sleep catches up).
        let paced = |w: &mut Writer, n: u64, period: Duration| {
            let t0 = Instant::now();
            for k in 1..=n {
                let due = t0 + period * k as u32;
                std::thread::sleep(due.saturating_duration_since(Instant::now()));
                publish(w);
            }
        };
        paced(&mut w, 30, Duration::from_millis(10));
        let burst_from = w.last_frame_index();
        paced(&mut w, 200, Duration::from_millis(1));
        w.stop(); // wakes every bit: ends the wait if the burst did not
        let (woken, lfi) = waiter.join().unwrap();
        assert_eq!(woken, sys::FutexWait::Woken);
        let chunks = (lfi - burst_from) / NFPC;
        // 0.9 chunk of lead per publish: 16 chunks after 18 publishes, the far bit with the 19th.
        assert!(
            lfi > burst_from,
            "woken at frame {lfi} by a publish at the nominal rate (burst from {burst_from})"
        );
        assert!(
            (18..150).contains(&chunks),
            "woken {chunks} chunks into the burst (lfi {lfi}, burst from {burst_from})"
        );
        w.remove().unwrap();
        std::fs::remove_dir_all(&dir).ok();
    }
}
