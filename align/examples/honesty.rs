//! Whether the error estimate bounds the true misalignment: per scenario and seed, the
//! true misalignment of every chunk (the resampler's position against the clocks' truth)
//! against the estimate, after lock.
//!
//! `cargo run --release -p bass-align --example honesty -- SEEDS SECONDS` (`HON_PPM=87,1000`,
//! `HON_SLEW=0,1`: the scenarios; `HON_SEED0=20`: seeds from 21; `V=1`: a line per run).

use align::sim::{Rig, Source};
use align::timeline::TimeLine;
use align::{Aligner, Config};

type Parts = (f64, f64, f64, f64);

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seeds: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(6);
    let seconds: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(16.0);
    let hz = 48_000.0;
    let mut all_true = Vec::new();
    let mut all_ratio = Vec::new();
    let (mut over, mut locked_chunks) = (0usize, 0usize);
    let mut locks = Vec::new();
    let mut bins = vec![Vec::new(); 8];
    // Per locked chunk: the master's and the follower's line error, the target's error and
    // the controller's, samples.
    let mut parts: Vec<Parts> = Vec::new();
    let list = |name: &str, d: &str| -> Vec<f64> {
        std::env::var(name).unwrap_or(d.into()).split(',').map(|v| v.parse().unwrap()).collect()
    };
    for ppm in list("HON_PPM", "87,-143,1000") {
        for slew in list("HON_SLEW", "0,1") {
            let s0: u64 = std::env::var("HON_SEED0").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
            for seed in s0 + 1..=s0 + seeds {
                let mut rig = Rig::standard(ppm, slew, seed);
                let cfg = Config::new(hz, 2);
                let mut al = Aligner::new(cfg, &[2]).unwrap();
                let (mut ml, mut fl): (Option<TimeLine>, Option<TimeLine>) = (None, None);
                let mut origin = None::<u64>;
                let (mc, fc) = (rig.master.clock, rig.followers[0].clock);
                let mut done = 0usize;
                let mut lock = None;
                let mut worst = 0.0f64;
                while done < (seconds * hz) as usize {
                    let (src, ch) = rig.next_event();
                    let o = *origin.get_or_insert(ch.stamp_ns);
                    match src {
                        Source::Master => {
                            ml.get_or_insert_with(|| TimeLine::new(hz, cfg.window_s, o))
                                .push(ch.first_frame as f64, ch.stamp_ns);
                            al.push_master(ch.as_chunk()).unwrap()
                        }
                        Source::Follower(i) => {
                            fl.get_or_insert_with(|| TimeLine::new(hz, cfg.window_s, o))
                                .push(ch.first_frame as f64, ch.stamp_ns);
                            al.push_follower(i, ch.as_chunk()).unwrap()
                        }
                    }
                    while let Some(out) = al.pop() {
                        let f = &out.followers[0];
                        let k = out.master_frame;
                        done += out.frames;
                        if !f.controller_error.is_finite() {
                            continue;
                        }
                        let (m, fo) = (ml.as_ref().unwrap(), fl.as_ref().unwrap());
                        let p = fo.frame_at(m.time_of(k as f64).unwrap()).unwrap();
                        let truth = fc.frame_at(mc.instant(k as f64));
                        let true_err = (p - truth) - f.controller_error;
                        if f.locked {
                            let ms = rig.master.jitter.min_s;
                            let m0 = align::sim::MONOTONIC_ORIGIN_S - o as f64 * 1e-9;
                            let me = (m.time_of(k as f64).unwrap() - mc.instant(k as f64) - ms - m0) * hz;
                            let fe = (fo.time_of(truth).unwrap() - fc.instant(truth) - ms - m0) * hz;
                            parts.push((me, fe, p - truth, f.controller_error));
                        }
                        let lines = f.error_estimate - f.controller_error.abs();
                        if f.locked {
                            lock.get_or_insert(k as f64 / hz);
                            locked_chunks += 1;
                            if true_err.abs() > f.error_estimate {
                                over += 1;
                            }
                            all_true.push(true_err);
                            bins[((k as f64 / hz / 2.0) as usize).min(7)].push(true_err.abs());
                            all_ratio.push((true_err.abs() - f.controller_error.abs()) / lines);
                            worst = worst.max(true_err.abs());
                        }
                    }
                }
                if std::env::var("V").is_ok() {
                    let tail = &all_true[all_true.len().saturating_sub(1000)..];
                    let mean = tail.iter().sum::<f64>() / tail.len().max(1) as f64;
                    println!(
                        "ppm {ppm:+5} slew {slew} seed {seed}: lock {lock:?} worst {worst:.3} mean {mean:.3}"
                    );
                }
                locks.push(lock.unwrap_or(f64::INFINITY));
            }
        }
    }
    let q = |v: &mut Vec<f64>, p: f64| {
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        v[((v.len() - 1) as f64 * p).round() as usize]
    };
    let rms = (all_true.iter().map(|x| x * x).sum::<f64>() / all_true.len() as f64).sqrt();
    let mut abs: Vec<f64> = all_true.iter().map(|x| x.abs()).collect();
    println!(
        "locked chunks {locked_chunks}: true RMS {rms:.4} p99 {:.4} p99.9 {:.4} max {:.4}; |true|/lines p50 {:.2} p99 {:.2} p99.9 {:.2}; over the estimate {over} ({:.3} %)",
        q(&mut abs, 0.99),
        q(&mut abs, 0.999),
        q(&mut abs, 1.0),
        q(&mut all_ratio, 0.5),
        q(&mut all_ratio, 0.99),
        q(&mut all_ratio, 0.999),
        100.0 * over as f64 / locked_chunks.max(1) as f64
    );
    for (i, b) in bins.iter_mut().enumerate() {
        if !b.is_empty() {
            let r = (b.iter().map(|x| x * x).sum::<f64>() / b.len() as f64).sqrt();
            println!("  {}-{} s: RMS {r:.4} p99.9 {:.4} max {:.4}", 2 * i, 2 * i + 2, q(b, 0.999), q(b, 1.0));
        }
    }
    let r = |f: &dyn Fn(&Parts) -> f64| {
        (parts.iter().map(|p| f(p) * f(p)).sum::<f64>() / parts.len() as f64).sqrt()
    };
    println!(
        "RMS: master line {:.4} follower line {:.4} target {:.4} controller {:.4}",
        r(&|p| p.0),
        r(&|p| p.1),
        r(&|p| p.2),
        r(&|p| p.3)
    );
    let n_inf = locks.iter().filter(|l| l.is_infinite()).count();
    println!(
        "lock s: median {:.2} max {:.2} (no lock in {n_inf} of {})",
        q(&mut locks, 0.5),
        q(&mut locks, 1.0),
        locks.len()
    );
}
