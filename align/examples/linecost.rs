//! The time line's cost per second of stamps at a chunk size: `linecost FRAMES SECONDS`.
use align::sim::{Clock, Rng};
use align::timeline::TimeLine;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let frames: u64 = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(64);
    let secs: f64 = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(40.0);
    let clock = Clock { nominal_hz: 48_000.0, ppm: 87.0, slew_ppm_per_s: 0.5, start_s: 0.0 };
    let mut line = TimeLine::new(48_000.0, 4.0, 0);
    let mut rng = Rng::new(1);
    let n = (secs * 48_000.0 / frames as f64) as u64;
    let warm = n / 2;
    let mut t0 = std::time::Instant::now();
    for k in 0..n {
        if k == warm {
            t0 = std::time::Instant::now();
        }
        let f = (k * frames) as f64;
        let t = clock.instant(f) + 50e-6 + rng.next_f64() * 150e-6;
        line.push(f, (t * 1e9) as u64);
    }
    let per_s = t0.elapsed().as_secs_f64() / (secs / 2.0);
    println!(
        "{frames}-frame chunks: {:.3} % of a core per card (window full), {} points",
        per_s * 100.0,
        line.len()
    );
}
