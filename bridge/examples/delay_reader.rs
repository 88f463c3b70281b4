//! Benchmark reader (scripts/bench-network.sh): waits for every chunk of a port for SECONDS
//! and measures the delay from the capture of the chunk's last frame to the reader's wake-up.
//! The capture time is the chunk table's CLOCK_MONOTONIC plus nFPC / rate (on a replica: the
//! source time mapped to the local clock). Prints one JSON line: count, p50, p99, p99.9 and
//! max in µs, and the frames it accounted for: `span` (from the first chunk read to the last),
//! `data` (read with samples), `gap` (read as GAP: the mirror published them as lost) and
//! `lapped` (gone from the port before this reader got to them); span = data + gap + lapped.
//!
//! usage: delay_reader NAME SECONDS
//! Environment: DELAY_READER_RT=P waits at SCHED_FIFO priority P (a real-time client);
//! DELAY_TRACE=FILE writes "first_frame mono_ns wake_ns" per chunk (scripts/bench-net-stages.py).

use std::time::{Duration, Instant};

use bassport::format::chunk_flags;
use bassport::{sys, Port};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let name = a.get(1).expect("NAME");
    let secs: f64 = a.get(2).and_then(|s| s.parse().ok()).expect("SECONDS");
    if let Some(p) = std::env::var("DELAY_READER_RT").ok().and_then(|p| p.parse::<i32>().ok()) {
        if p > 0 {
            sys::sched::set_fifo(p).unwrap_or_else(|e| panic!("SCHED_FIFO {p}: errno {e}"));
        }
    }
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
    let first = nfr;
    let mut bufs = vec![vec![0i32; nfpc as usize]; g.channels as usize];
    let mut delays = Vec::new();
    let mut trace = Vec::new();
    let (mut data, mut gap, mut lapped) = (0u64, 0u64, 0u64);
    while Instant::now() < end {
        if port.wait(nfr + nfpc - 1, Duration::from_secs(1)).is_err() {
            continue;
        }
        let now = sys::monotonic_ns();
        let ci = port.chunk_info(nfr).ok();
        if let Some(ci) = ci {
            let due = ci.mono_ns + chunk_ns;
            delays.push(now.saturating_sub(due) as f64 / 1e3);
            trace.push((nfr, ci.mono_ns, now));
        }
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        if let Ok(r) = port.get_audio_data(nfpc as usize, &mut nfr, &mut outs) {
            lapped += r.loss;
            match ci {
                Some(ci) if ci.flags & chunk_flags::GAP != 0 => gap += r.frames as u64,
                _ => data += r.frames as u64,
            }
        }
    }
    if let Some(p) = std::env::var_os("DELAY_TRACE") {
        let text: String = trace.iter().map(|(f, m, w)| format!("{f} {m} {w}\n")).collect();
        std::fs::write(p, text).expect("DELAY_TRACE");
    }
    delays.sort_by(|x, y| x.total_cmp(y));
    let q =
        |p: f64| delays.get(((delays.len() as f64 - 1.0) * p).round() as usize).copied().unwrap_or(f64::NAN);
    println!(
        "{{\"count\":{},\"p50_us\":{:.1},\"p99_us\":{:.1},\"p999_us\":{:.1},\"max_us\":{:.1},\
         \"span\":{},\"data\":{data},\"gap\":{gap},\"lapped\":{lapped}}}",
        delays.len(),
        q(0.5),
        q(0.99),
        q(0.999),
        q(1.0),
        nfr - first
    );
}
