//! Benchmark reader (scripts/bench-network.sh): waits for every chunk of a port for SECONDS
//! and measures the delay from the capture of the chunk's last frame to the reader's wake-up.
//! The capture time is the chunk table's CLOCK_MONOTONIC plus nFPC / rate (on a replica: the
//! source time mapped to the local clock). Prints one JSON line: count, p50, p99 in µs.
//!
//! usage: delay_reader NAME SECONDS

use std::time::{Duration, Instant};

use bassport::{sys, Port};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let name = a.get(1).expect("NAME");
    let secs: f64 = a.get(2).and_then(|s| s.parse().ok()).expect("SECONDS");
    let end = Instant::now() + Duration::from_secs_f64(secs);
    let port = loop {
        if let Ok(p) = Port::open(name) {
            if p.info().map(|i| i.last_frame_index > 0).unwrap_or(false) {
                break p;
            }
        }
        assert!(Instant::now() < end, "no port {name}");
        std::thread::sleep(Duration::from_millis(20));
    };
    let g = port.geometry().clone();
    let nfpc = u64::from(g.frames_per_chunk);
    let chunk_ns = nfpc * 1_000_000_000 / u64::from(g.sample_rate);
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let mut bufs = vec![vec![0i32; nfpc as usize]; g.channels as usize];
    let mut delays = Vec::new();
    while Instant::now() < end {
        if port.wait(nfr + nfpc - 1, Duration::from_secs(1)).is_err() {
            continue;
        }
        let now = sys::monotonic_ns();
        if let Ok(ci) = port.chunk_info(nfr) {
            let due = ci.mono_ns + chunk_ns;
            delays.push(now.saturating_sub(due) as f64 / 1e3);
        }
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        let _ = port.get_audio_data(nfpc as usize, &mut nfr, &mut outs);
    }
    delays.sort_by(|x, y| x.total_cmp(y));
    let q =
        |p: f64| delays.get(((delays.len() as f64 - 1.0) * p).round() as usize).copied().unwrap_or(f64::NAN);
    println!("{{\"count\":{},\"p50_us\":{:.1},\"p99_us\":{:.1}}}", delays.len(), q(0.5), q(0.99));
}
