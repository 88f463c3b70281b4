//! The jack-plugin pair's stamps replayed through the aligner (evidence for
//! docs/multi-device.md, *The jack-plugin pair*): one run of `alsa_jack_pair.rs`'s setup
//! (jackd dummy at 48 kHz, 1024-frame periods, SCHED_FIFO; bassd at `--rt-priority 5`)
//! recorded the master's chunk stamps (`first_frame mono_ns`, from the port) and the
//! follower's reads (`frames mono_ns`, from bassd's `trace` log). Both PCMs run on one clock,
//! so an aligner that models the cards' clocks from such stamps should lock.
//!
//! It does not: the error estimate stays at 0.2–5 samples for the 11 s and never holds the
//! 0.25-sample bound for bassd's 1.5 s. The first test is that finding, left failing for the
//! aligner's owner (`#[ignore]`, run with `--ignored`); the second checks the data itself:
//! its stamps lie on one 48 kHz clock within the jitter measured (so the failure is the
//! aligner's tolerance of that jitter, not broken stamps).

use align::{Aligner, Chunk, Config};

const RATE: f64 = 48000.0;

fn rows(text: &str) -> Rows {
    text.lines()
        .map(|l| {
            let mut v = l.split(' ').map(|x| x.parse::<u64>().expect("a number"));
            (v.next().expect("two columns"), v.next().expect("two columns"))
        })
        .collect()
}

/// Rows of two numbers: (first frame or frames, stamp in ns).
type Rows = Vec<(u64, u64)>;

/// (master chunks: first frame, stamp), (follower reads: frames, stamp).
fn data() -> (Rows, Rows) {
    (
        rows(include_str!("data/jack_pair_master_stamps.txt")),
        rows(include_str!("data/jack_pair_follower_stamps.txt")),
    )
}

#[test]
fn the_recorded_stamps_are_one_clock_within_their_jitter() {
    let (m, f) = data();
    assert!(m.len() > 1000 && f.len() > 1500);
    // Each card's frames against its stamps: the smallest stamp minus nominal time per
    // second (the floor) stays within 200 µs over the run — one steady clock, no timebase
    // step (a step is milliseconds).
    let floor = |pts: &[(u64, u64)]| -> Vec<f64> {
        let (f0, t0) = pts[0];
        let mut per_s = vec![f64::MAX; 12];
        for &(n, t) in pts {
            let r = (t as f64 - t0 as f64) / 1e3 - (n - f0) as f64 / RATE * 1e6;
            let s = ((n - f0) as f64 / RATE) as usize;
            if s < per_s.len() {
                per_s[s] = per_s[s].min(r);
            }
        }
        per_s.into_iter().filter(|v| *v < f64::MAX).collect()
    };
    let master: Vec<(u64, u64)> = m.iter().map(|&(k, t)| (k - 1, t)).collect();
    let mut n = 0;
    let follower: Vec<(u64, u64)> = f
        .iter()
        .map(|&(frames, t)| {
            let p = (n, t);
            n += frames;
            p
        })
        .collect();
    for (name, fl) in [("master", floor(&master)), ("follower", floor(&follower))] {
        let (lo, hi) = fl.iter().fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        assert!(hi - lo < 200.0, "{name}: per-second stamp floor spans {lo:.0}..{hi:.0} µs: {fl:?}");
    }
}

#[test]
#[ignore = "open: the aligner does not lock on the jack plugin's stamps (docs/multi-device.md)"]
fn the_aligner_locks_on_the_jack_pairs_stamps() {
    let (m, f) = data();
    let mut cfg = Config::new(RATE, 2);
    cfg.lock_hold_s = 1.5; // bassd's (broker/src/capture/multi.rs LOCK_HOLD_S)
    let mut a = Aligner::new(cfg, &[2]).expect("aligner");
    let zeros = vec![0i32; 2048 * 2];
    // Delivered in the order their last frame was due.
    let mut ev: Vec<(u64, bool, usize, u64)> =
        m.iter().map(|&(_, t)| (t + 10_000_000, true, 480, t)).collect();
    ev.extend(f.iter().map(|&(n, t)| (t + n * 1_000_000_000 / 48_000, false, n as usize, t)));
    ev.sort_unstable();
    let (mut locked_at, mut errors) = (None, Vec::new());
    for (_, is_master, frames, stamp_ns) in ev {
        let c = Chunk { samples: &zeros[..frames * 2], frames, stamp_ns, after_gap: false };
        if is_master {
            a.push_master(c).expect("master chunk");
        } else {
            let _ = a.push_follower(0, c);
        }
        while let Some(x) = a.pop() {
            let fo = &x.followers[0];
            if x.master_frame % 24_000 < 480 {
                errors.push((x.master_frame as f64 / RATE, fo.error_estimate));
            }
            if fo.locked && locked_at.is_none() {
                locked_at = Some(x.master_frame as f64 / RATE);
            }
        }
    }
    assert!(locked_at.is_some(), "never locked; error estimate every 0.5 s (s, samples): {errors:.2?}");
}
