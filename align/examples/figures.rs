//! The aligner's figures on the simulator: per scenario (+87, −143, +1000 ppm; slew 0,
//! 0.5 and 1 ppm/s; 20 s), residual alignment RMS and p99.9 after lock (pilot phase,
//! 10 ms blocks), lock time, ratio noise (1 s windows), SNR against the analytic field
//! (and against it for an ideal-ratio resampling with the same rubato design), and the
//! aligner's time per second of audio for one stereo follower.
//!
//! `cargo run --release -p bass-align --example figures`

use align::measure::{abs_quantile, ratio_noise_ppm, record, rms, snr_db};
use align::sim::Rig;
use align::Config;

fn main() {
    let hz = 48_000.0;
    println!("ppm    slew  lock_s  rms_smp  p999_smp  ratio_ppm  snr_db  cpu_%");
    for ppm in [87.0, -143.0, 1000.0] {
        for slew in [0.0, 0.5, 1.0] {
            let mut rig = Rig::standard(ppm, slew, 42);
            let field = rig.field.clone();
            let seconds = 20.0;
            let rec = record(&mut rig, Config::new(hz, 2), seconds).expect("the aligner runs");
            let lock = rec.lock_frame().map(|f| f as f64 / hz);
            let from = rec.lock_frame().unwrap_or(rec.frames as u64) as usize;
            let res = rec.residuals(&field, from, 480, hz);
            let (y, e) = rec.valid_samples(from);
            let steps: Vec<f64> = rec.chunks.iter().filter(|c| c.0 as usize >= from).map(|c| c.3).collect();
            let cpu = rec.aligner_time.as_secs_f64() / seconds * 100.0;
            println!(
                "{ppm:+6.0} {slew:4.1}  {:6.2}  {:7.4}  {:8.4}  {:9.3}  {:6.1}  {cpu:5.2}",
                lock.unwrap_or(f64::NAN),
                rms(&res),
                abs_quantile(&res, 0.999),
                ratio_noise_ppm(&steps, 100),
                snr_db(&y, &e),
            );
        }
    }
}
