//! The resampler's CPU per stereo follower: 10 s of 48 kHz audio in 480-frame calls at +87
//! ppm, linear against cubic interpolation of the sinc table, best of 5 each, side by side.
//!
//! `cargo run --release -p bass-align --example rsbench`

use align::resample::{Design, Stage};
use std::time::Instant;

fn time(design: Design) -> f64 {
    let n = 480;
    let x: Vec<f64> = (0..2000).map(|i| (i as f64 * 0.1).sin() * 0.5).collect();
    let mut st = Stage::new(design, 2, 1024, 1.0).expect("a stage");
    st.set_step(1.0 + 87e-6).expect("a step");
    let mut out = vec![Vec::new(), Vec::new()];
    let t = Instant::now();
    for _ in 0..1000 {
        let need = st.input_needed(n).expect("input");
        st.process(&[&x[..need], &x[..need]], n, &mut out).expect("process");
    }
    t.elapsed().as_secs_f64()
}

fn main() {
    let (mut lin, mut cub) = (f64::INFINITY, f64::INFINITY);
    for _ in 0..5 {
        lin = lin.min(time(Design::standard()));
        cub = cub.min(time(Design { cubic: true, ..Design::standard() }));
    }
    // 1000 calls of 480 frames: 10 s of audio.
    println!("stereo, % of a core: linear {:.2}, cubic {:.2}", lin / 10.0 * 100.0, cub / 10.0 * 100.0);
}
