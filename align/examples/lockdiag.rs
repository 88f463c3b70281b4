//! Where the alignment error comes from, chunk by chunk, in the simulator: the error estimate
//! and the lines' uncertainty term, each card's line error at the evaluated frame and their
//! difference (`line_err`: the target's error), the true misalignment from the pilots'
//! phase, and the lock; then the lock time, the worst true error after it and the worst
//! under-report (true error minus estimate).
//!
//! `cargo run --release -p bass-align --example lockdiag -- SEED [MASTER_JITTER 1|0] [HOLD_S] [PPM] [SLEW]`
//! (`V=1`: a line every 50 ms; `W=8`: an 8 s window; `R=1`: line error / uncertainty on stderr).

use align::measure::pilot_shift;
use align::sim::{Jitter, Rig, Source, FULL_SCALE};
use align::timeline::TimeLine;
use align::{Aligner, Config};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(42);
    let master_jitter: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1.0);
    let hold: f64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(0.5);
    let ppm: f64 = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(87.0);
    let slew: f64 = args.get(5).and_then(|s| s.parse().ok()).unwrap_or(0.0);
    let hz = 48_000.0;
    let mut rig = Rig::standard(ppm, slew, seed);
    if master_jitter == 0.0 {
        rig.master.jitter = Jitter { min_s: 50e-6, max_s: 50e-6, late_probability: 0.0, late_max_s: 0.0 };
    }
    let field = rig.field.clone();
    let mut cfg = Config::new(hz, 2);
    cfg.lock_hold_s = hold;
    let win: f64 = std::env::var("W").ok().and_then(|v| v.parse().ok()).unwrap_or(4.0);
    cfg.window_s = win;
    let mut al = Aligner::new(cfg, &[2]).unwrap();
    let origin = None::<u64>;
    let mut origin = origin;
    let (mut ml, mut fl): (Option<TimeLine>, Option<TimeLine>) = (None, None);
    let mut lock = None;
    let mut worst_after = 0.0f64;
    let mut worst_under = f64::NEG_INFINITY;
    let v = std::env::var("V").is_ok();
    let (mc, fc) = (rig.master.clock, rig.followers[0].clock);
    let mut done = 0usize;
    let mut m_start = f64::NAN;
    while done < (14.0 * hz) as usize {
        let (src, ch) = rig.next_event();
        let o = *origin.get_or_insert(ch.stamp_ns);
        if m_start.is_nan() {
            m_start = align::sim::MONOTONIC_ORIGIN_S - o as f64 * 1e-9;
        }
        match src {
            Source::Master => {
                ml.get_or_insert_with(|| TimeLine::new(hz, win, o)).push(ch.first_frame as f64, ch.stamp_ns);
                al.push_master(ch.as_chunk()).unwrap()
            }
            Source::Follower(i) => {
                fl.get_or_insert_with(|| TimeLine::new(hz, win, o)).push(ch.first_frame as f64, ch.stamp_ns);
                al.push_follower(i, ch.as_chunk()).unwrap()
            }
        }
        while let Some(out) = al.pop() {
            let f = &out.followers[0];
            let k = out.master_frame;
            done += out.frames;
            let (m, fo) = (ml.as_ref().unwrap(), fl.as_ref().unwrap());
            let p = fo.frame_at(m.time_of(k as f64).unwrap()).unwrap();
            let truth = fc.frame_at(mc.instant(k as f64));
            let line_err = p - truth;
            let mo = rig.master.jitter.min_s;
            let _ = mo;
            let merr =
                (m.time_of(k as f64).unwrap() - (mc.instant(k as f64) - mc.start_s) - 50e-6 - (m_start)) * hz;
            let fk = fc.frame_at(mc.instant(k as f64));
            let ferr = (fo.time_of(fk).unwrap() - (fc.instant(fk)) - 50e-6 - m_start) * hz;
            let unc = (m.line().unwrap().uncertainty_s + fo.line().unwrap().uncertainty_s) * hz;
            let mut r = f64::NAN;
            if f.valid.iter().all(|&x| x) {
                let t: Vec<f64> = (0..out.frames).map(|j| mc.instant((k + j as u64) as f64)).collect();
                let mut s = 0.0;
                for c in 0..2 {
                    let y: Vec<f64> =
                        (0..out.frames).map(|j| f64::from(f.samples[j * 2 + c]) / FULL_SCALE).collect();
                    s += pilot_shift(&field, c, &y, &t, hz).unwrap();
                }
                r = s / 2.0;
            }
            if k as f64 / hz > 0.3 && unc > 0.0 && std::env::var("R").is_ok() {
                eprintln!(
                    "{} {} {}",
                    k as f64 / hz,
                    line_err / unc,
                    r - (f.error_estimate - unc).abs().copysign(r)
                );
            }
            if f.locked && lock.is_none() {
                lock = Some(k as f64 / hz);
            }
            if lock.is_some() && r.is_finite() {
                worst_after = worst_after.max(r.abs());
                worst_under = worst_under.max(r.abs() - f.error_estimate);
            }
            if v && k % 2400 == 0 {
                println!(
                    "{:6.2} m {:7.4} f {:7.4} est {:7.4} unc {:6.4} line_err {:7.4} true {:7.4} ctl~ {:7.4} locked {}",
                    k as f64 / hz, merr, ferr, f.error_estimate, unc, line_err, r, f.error_estimate - unc, f.locked
                );
            }
        }
    }
    println!("seed {seed} mj {master_jitter} hold {hold} ppm {ppm} slew {slew}: lock {lock:?} s worst_after {worst_after:.4} worst under-report {worst_under:.4}");
}
