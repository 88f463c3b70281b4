//! Part 7, second table: callback APIs side by side — bass callback streams
//! (`bassport::stream::Stream`, one chunk per block) against JACK clients' process callbacks
//! on jackd's dummy backend, at 1, 8 and 64 client processes, in the same run.
//!
//! - JACK: `jackd -r -d dummy -r 48000 -p 256` (no realtime, as the bass side), N processes
//!   (`child jack-cb-client`), each a JACK client (bench/src/jack.rs: libjack by dlopen, two
//!   ports connected to system:capture_1/2) recording per period callback entered − the cycle
//!   start JACK reports (`jack_get_cycle_times`: the period start, on jack_get_time's clock).
//! - bass: `bassd --rt-priority 0 --acquire sim:pattern` at 256-frame chunks, N processes
//!   (`child cb-stream`) with a callback stream each, recording per block callback entered −
//!   the chunk's due time (its first frame's stamp + one chunk: the capture thread's timer
//!   target, the same reference as part 7's table).
//!
//! Both references are "the period is over and its data can be had"; JACK's is its DLL-filtered
//! estimate of the cycle start, bass's the simulated device's exact due time.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use bassport::sys::monotonic_ns;

use crate::e2e::Proc;
use crate::procs::Child;
use crate::stats::{fmt_ns, median, quantile};
use crate::workload::{CLIENTS, QUANTUM, RATE};

/// Per client count: (JACK delays, bass callback stream delays), ns.
#[derive(Clone, Debug, Default)]
pub struct CallbackResults {
    /// Per client count.
    pub rows: BTreeMap<usize, (Vec<f64>, Vec<f64>)>,
    /// Seconds per system and client count.
    pub seconds: f64,
    /// Why (some of) it did not run.
    pub skipped: Option<String>,
}

/// The JACK server's name (fixed: JACK frees a killed server's slot only on a restart of
/// the same name).
const SERVER: &str = "bass-bench-cb";

/// Delays from a child's lines `ENTERED DELAY` (or `DELAY`) inside `window` (entered, ns).
pub fn delays(lines: &[String], window: Option<(u64, u64)>) -> Vec<f64> {
    lines
        .iter()
        .filter_map(|l| {
            let v: Vec<u64> = l.split_whitespace().filter_map(|x| x.parse().ok()).collect();
            match (&v[..], window) {
                (&[t, d], Some((a, b))) if t >= a && t <= b => Some(d as f64),
                (&[_, _], Some(_)) => None,
                (&[d], None) => Some(d as f64),
                _ => None,
            }
        })
        .collect()
}

fn jack_round(n: usize, secs: f64) -> Result<Vec<f64>, String> {
    let jackd = Command::new("jackd")
        .args(["-r", "-n", SERVER, "-d", "dummy", "-r"])
        .arg(RATE.to_string())
        .args(["-C", "2", "-P", "0", "-p"])
        .arg(QUANTUM.to_string())
        .env("JACK_NO_AUDIO_RESERVATION", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("jackd: {e}"))?;
    let jackd = Proc(jackd);
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let mut kids = Vec::new();
    for _ in 0..n {
        let mut cmd = Command::new(&exe);
        cmd.args(["child", "jack-cb-client", &secs.to_string()]).env("JACK_DEFAULT_SERVER", SERVER);
        kids.push(Child::spawn_command(cmd));
    }
    let mut failed = None;
    for k in &mut kids {
        let l = k.line();
        if l != "ready" {
            failed.get_or_insert(l);
        }
    }
    let mut all = Vec::new();
    for k in kids {
        all.extend(delays(&k.finish(), None));
    }
    drop(jackd);
    match failed {
        Some(why) => Err(format!("a JACK client of {n}: {why}")),
        None => Ok(all),
    }
}

fn bass_round(bassd: &Path, n: usize, secs: f64) -> Result<Vec<f64>, String> {
    let name = format!("bench-cb-{n}");
    let d = Command::new(bassd)
        .args(["--name", &name, "--rt-priority", "0", "--acquire", "sim:pattern", "--rate"])
        .arg(RATE.to_string())
        .args(["--frames", &QUANTUM.to_string(), "--chunks", "375"])
        .env("BASS_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .map_err(|e| format!("start bassd: {e}"))?;
    let d = Proc(d);
    let t = Instant::now();
    while bassport::Port::open(&name).is_err() {
        if t.elapsed() > Duration::from_secs(10) {
            return Err("bassd did not create its port within 10 s".into());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let kids = crate::procs::spawn_ready(n, "cb-stream", std::slice::from_ref(&name));
    std::thread::sleep(Duration::from_millis(300));
    let w0 = monotonic_ns();
    std::thread::sleep(Duration::from_secs_f64(secs));
    let w1 = monotonic_ns();
    drop(d);
    Ok(kids.into_iter().flat_map(|k| delays(&k.finish(), Some((w0, w1)))).collect())
}

/// Child: a JACK client for `SECS` seconds (after a 300 ms settle); prints `ready` (or why
/// not), then its process callbacks' delays from the cycle start (ns), one per line.
pub fn child_jack_client(args: &[String]) {
    let secs: f64 = args.first().and_then(|s| s.parse().ok()).unwrap_or(5.0);
    let name = format!("bb{}", std::process::id());
    let t = Instant::now();
    let jack = loop {
        match crate::jack::JackClient::start(&name) {
            Ok(c) => break c,
            Err(e) if t.elapsed() > Duration::from_secs(5) => {
                println!("{e}");
                return;
            }
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    };
    crate::procs::say_ready();
    std::thread::sleep(Duration::from_millis(300));
    jack.reset();
    std::thread::sleep(Duration::from_secs_f64(secs));
    let v = jack.delays_ns();
    drop(jack);
    let mut out = String::with_capacity(v.len() * 12);
    for d in v {
        out.push_str(&format!("{d:.0}\n"));
    }
    print!("{out}");
}

/// Child: a bass callback stream on port `NAME`, one chunk per block, until the port stops;
/// prints `ENTERED DELAY` per block (delay = entered − the chunk's due time, ns). The callback
/// writes into a preallocated table.
pub fn child_stream(args: &[String]) {
    use bassport::stream::{Config, Control, Event, Stream};
    let cfg = Config { frames_per_call: QUANTUM as usize, ..Config::default() };
    let mut stream = Stream::open(&args[0], cfg).expect("open stream");
    let mut rec: Vec<(u64, u64)> = Vec::with_capacity(1 << 16);
    crate::procs::say_ready();
    let _ = stream.run(
        |b| {
            let entered = monotonic_ns();
            let due = b.mono_ns + b.frames as u64 * 1_000_000_000 / u64::from(RATE);
            if b.mono_ns > 0 && rec.len() < rec.capacity() {
                rec.push((entered, entered.saturating_sub(due)));
            }
            Control::Continue
        },
        |e| match e {
            Event::RealtimeRefused { .. } => Control::Continue,
            _ => Control::Stop,
        },
    );
    let mut out = String::with_capacity(rec.len() * 24);
    for (t, d) in &rec {
        out.push_str(&format!("{t} {d}\n"));
    }
    print!("{out}");
}

/// Runs the comparison at 1, 8 and 64 clients, JACK then bass at each count.
pub fn run(bassd: &Path, secs: f64) -> CallbackResults {
    let mut res = CallbackResults { seconds: secs, ..CallbackResults::default() };
    if Command::new("jackd").arg("--version").stdout(Stdio::null()).stderr(Stdio::null()).status().is_err() {
        res.skipped = Some("jackd not found (jackd2)".into());
        return res;
    }
    for &n in CLIENTS {
        let jack = match jack_round(n, secs) {
            Ok(v) => v,
            Err(e) => {
                println!("  JACK, {n} clients: {e}");
                res.skipped = Some(e);
                continue;
            }
        };
        let bass = match bass_round(bassd, n, secs) {
            Ok(v) => v,
            Err(e) => {
                println!("  bass callback streams, {n} clients: {e}");
                res.skipped = Some(e);
                continue;
            }
        };
        println!(
            "  callbacks, {n:>2} client{}: JACK process callback − cycle start p50 {} p99 {} ({}) | bass callback stream − chunk due p50 {} p99 {} ({})",
            if n == 1 { "" } else { "s" },
            fmt_ns(median(&jack)),
            fmt_ns(quantile(&jack, 0.99)),
            jack.len(),
            fmt_ns(median(&bass)),
            fmt_ns(quantile(&bass, 0.99)),
            bass.len()
        );
        res.rows.insert(n, (jack, bass));
    }
    res
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delays_keep_the_window_and_read_both_line_forms() {
        let l: Vec<String> =
            ["ready", "100 7", "200 8", "900 9", "cycles=3"].iter().map(|s| s.to_string()).collect();
        assert_eq!(delays(&l, Some((150, 800))), vec![8.0]);
        let j: Vec<String> = ["5000", "6000", "x"].iter().map(|s| s.to_string()).collect();
        assert_eq!(delays(&j, None), vec![5000.0, 6000.0]);
    }
}
