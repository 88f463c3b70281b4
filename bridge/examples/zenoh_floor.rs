//! Benchmark helper (scripts/bench-network.sh): bare Zenoh at bass-bridge's message rate, no
//! bass at all, to measure the CPU floor of one Zenoh message per chunk on this machine.
//!
//! `pub` puts messages of BYTES bytes at RATE per second (absolute-deadline pacing, as bassd's
//! simulated device) for SECONDS, on a session listening on ENDPOINT, with the publication
//! settings of `serve`'s chunk publisher (congestion control, express, priority: the constants
//! of `bass_bridge::net`). `sub` connects to ENDPOINT and counts them. Both
//! with multicast and gossip scouting off. Each prints one JSON line with its count.
//!
//! usage: zenoh_floor pub ENDPOINT RATE BYTES SECONDS
//!        zenoh_floor sub ENDPOINT SECONDS

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use bass_bridge::net::{CHUNK_CONGESTION, CHUNK_EXPRESS, CHUNK_PRIORITY};
use zenoh::Wait;

const KEY: &str = "bass-bench/floor";

fn session(listen: Option<&str>, connect: Option<&str>) -> zenoh::Session {
    let mut c = zenoh::Config::default();
    let mut set = |k: &str, v: String| c.insert_json5(k, &v).unwrap_or_else(|e| panic!("{k} = {v}: {e}"));
    set("scouting/multicast/enabled", "false".into());
    set("scouting/gossip/enabled", "false".into());
    if let Some(e) = listen {
        set("listen/endpoints", format!("[{e:?}]"));
    }
    if let Some(e) = connect {
        set("connect/endpoints", format!("[{e:?}]"));
    }
    zenoh::open(c).wait().expect("open the Zenoh session")
}

fn arg<T: std::str::FromStr>(a: &[String], i: usize, what: &str) -> T {
    a.get(i).and_then(|s| s.parse().ok()).unwrap_or_else(|| panic!("{what} (argument {i})"))
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    match a.get(1).map(String::as_str) {
        Some("pub") => {
            let (endpoint, rate, bytes, secs): (String, f64, usize, f64) =
                (arg(&a, 2, "ENDPOINT"), arg(&a, 3, "RATE"), arg(&a, 4, "BYTES"), arg(&a, 5, "SECONDS"));
            let s = session(Some(&endpoint), None);
            let publisher = s
                .declare_publisher(KEY)
                .congestion_control(CHUNK_CONGESTION)
                .express(CHUNK_EXPRESS)
                .priority(CHUNK_PRIORITY)
                .wait()
                .expect("declare the publisher");
            let payload = vec![0x5au8; bytes];
            let period = Duration::from_secs_f64(1.0 / rate);
            let start = Instant::now();
            let mut sent = 0u64;
            while start.elapsed().as_secs_f64() < secs {
                publisher.put(payload.clone()).wait().expect("put");
                sent += 1;
                let due = start + period * u32::try_from(sent).unwrap_or(u32::MAX);
                if let Some(d) = due.checked_duration_since(Instant::now()) {
                    std::thread::sleep(d);
                }
            }
            println!("{{\"sent\": {sent}}}");
        }
        Some("sub") => {
            let (endpoint, secs): (String, f64) = (arg(&a, 2, "ENDPOINT"), arg(&a, 3, "SECONDS"));
            let s = session(None, Some(&endpoint));
            let got = Arc::new(AtomicU64::new(0));
            let g = got.clone();
            let _sub = s
                .declare_subscriber(KEY)
                .callback(move |_| {
                    g.fetch_add(1, Ordering::Relaxed);
                })
                .wait()
                .expect("declare the subscriber");
            std::thread::sleep(Duration::from_secs_f64(secs));
            println!("{{\"received\": {}}}", got.load(Ordering::Relaxed));
        }
        _ => {
            eprintln!(
                "usage: zenoh_floor pub ENDPOINT RATE BYTES SECONDS | zenoh_floor sub ENDPOINT SECONDS"
            );
            std::process::exit(2);
        }
    }
}
