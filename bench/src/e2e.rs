//! Parts 4 and 5: bassd end to end through ALSA (jackd dummy backend → ALSA `jack` PCM →
//! bassd → reader) against a direct JACK client, and bassd's CPU.
//!
//! - jackd runs `-d dummy` at 48 kHz with the period under test; an ALSA configuration in
//!   the scratch directory (`ALSA_CONFIG_PATH`) defines a `jack` PCM on system:capture_1/2
//!   behind a `plug` (the jack plugin only speaks float).
//! - bassd (next to this binary) acquires that PCM with chunks of the period size; a reader
//!   (this process) waits on the port and records, per chunk, now − the chunk's timestamp
//!   (CLOCK_MONOTONIC of its first frame).
//! - at the same time a direct JACK client in this process records, per period, now − the
//!   time of the period's first frame (cycle start − one period).
//! - bassd's CPU: the sum of its threads' on-CPU time (/proc/PID/task/*/schedstat) over the
//!   measurement, as a share of one core; the same for the sim device (no ALSA) at 32, 64,
//!   256 and 2205-frame chunks, with a reader reading every chunk and one blocked in a wait
//!   for a frame one second ahead.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use bassport::{Error, Port, State};

use crate::procs::{field, spawn_ready, Child};
use crate::stats::{fmt_ns, median, quantile};

/// One end-to-end configuration.
#[derive(Clone, Debug, Default)]
pub struct E2eRow {
    /// JACK period = bass chunk (frames).
    pub period: u32,
    /// bass: delay from the start of the JACK cycle that made the chunk's last frame
    /// available to the reader having the chunk (ns).
    pub bass: Vec<f64>,
    /// Direct JACK client: delay from the cycle start to its process callback (ns).
    pub jack: Vec<f64>,
    /// bass: reader time − the chunk's timestamp (`mono_ns`, its first frame) (ns).
    pub bass_stamp: Vec<f64>,
    /// Spread of the jack_get_time vs CLOCK_MONOTONIC offset during the run (ns).
    pub clock_spread_ns: u64,
    /// bassd's CPU, share of one core.
    pub bassd_cpu: f64,
    /// jackd's CPU, share of one core.
    pub jackd_cpu: f64,
    /// Chunk flags seen (TIME_ESTIMATED etc.), OR-ed.
    pub flags: u32,
    /// Why the row is missing, if it is.
    pub skipped: Option<String>,
}

/// bassd's CPU on a simulated device.
#[derive(Clone, Debug, Default)]
pub struct CpuRow {
    /// Frames per chunk.
    pub chunk: u32,
    /// bassd, share of one core.
    pub bassd: f64,
    /// A reader reading every chunk, share of one core.
    pub reader: f64,
    /// A reader blocked in `wait` for a frame one second ahead, share of one core.
    pub waiter: f64,
    /// Times per second the waiting reader went to sleep (voluntary context switches).
    pub waiter_wakes: f64,
    /// bassd resident memory (KiB) at the end.
    pub bassd_rss: crate::procs::Rss,
}

/// Results of parts 4 and 5.
#[derive(Clone, Debug, Default)]
pub struct E2eResults {
    /// Part 4 (and bassd CPU through ALSA).
    pub e2e: Vec<E2eRow>,
    /// Part 5 on the simulated device.
    pub cpu: Vec<CpuRow>,
    /// Why nothing could run, if so.
    pub skipped: Option<String>,
    /// Seconds measured per configuration.
    pub seconds: f64,
}

pub(crate) fn bassd_path() -> Option<PathBuf> {
    let p = std::env::current_exe().ok()?.parent()?.join("bassd");
    p.exists().then_some(p)
}

/// On-CPU time of all threads of `pid` (ns).
pub(crate) fn cpu_ns(pid: u32) -> u64 {
    let Ok(dir) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return 0 };
    dir.filter_map(|e| e.ok())
        .filter_map(|e| std::fs::read_to_string(e.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next().and_then(|v| v.parse::<u64>().ok()))
        .sum()
}

/// A daemon process, ended with SIGTERM (then SIGKILL after 3 s) when dropped.
pub(crate) struct Proc(pub(crate) std::process::Child);

impl Drop for Proc {
    fn drop(&mut self) {
        // SAFETY: signalling our own child by its pid.
        unsafe { libc::kill(self.0.id() as libc::pid_t, libc::SIGTERM) };
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(3) {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_bassd(bassd: &Path, name: &str, device: &str, chunk: u32, chunks: u32) -> Result<Proc, String> {
    let child = Command::new(bassd)
        .args([
            "--name",
            name,
            "--allow-device",
            "bassjack",
            "--acquire",
            device,
            "--rate",
            "48000",
            "--frames",
        ])
        .arg(chunk.to_string())
        .args(["--chunks", &chunks.to_string()])
        .env("BASS_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .map_err(|e| format!("start bassd: {e}"))?;
    let p = Proc(child);
    let t = Instant::now();
    loop {
        if let Ok(port) = Port::open(name) {
            if port.info().map(|i| i.state == Some(State::Capturing)).unwrap_or(false) {
                return Ok(p);
            }
        }
        if t.elapsed() > Duration::from_secs(10) {
            return Err(format!("bassd did not start capturing {device} within 10 s"));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Reads every chunk for `d`; returns per wake (reader time, reader time − newest chunk's
/// timestamp) in ns, and the OR-ed chunk flags.
fn read_delays(name: &str, d: Duration) -> Result<(Vec<(u64, f64)>, u32), String> {
    let port = Port::open(name).map_err(|e| e.to_string())?;
    let mut nfr = port.info().map_err(|e| e.to_string())?.last_frame_index + 1;
    let cap = 48000;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let nfpc = u64::from(port.geometry().frames_per_chunk);
    let (mut out, mut flags) = (Vec::new(), 0);
    let start = Instant::now();
    while start.elapsed() < d {
        match port.wait(nfr, Duration::from_secs(2)) {
            Ok(lfi) => {
                let now = bassport::sys::monotonic_ns();
                let first = nfr;
                let mut bufs = [&mut l[..], &mut r[..]];
                port.get_audio_data(cap, &mut nfr, &mut bufs).map_err(|e| e.to_string())?;
                // The newest complete chunk: its delay is what a waiting reader sees.
                let newest = (lfi - 1) / nfpc * nfpc + 1;
                if newest >= first {
                    if let Ok(ci) = port.chunk_info(newest) {
                        out.push((now, now.saturating_sub(ci.mono_ns) as f64));
                        flags |= ci.flags;
                    }
                }
            }
            Err(Error::Timeout { .. }) => return Err("no chunk for 2 s".into()),
            Err(e) => return Err(e.to_string()),
        }
    }
    Ok((out, flags))
}

fn e2e_row(bassd: &Path, dir: &Path, period: u32, chunk: u32, secs: f64) -> E2eRow {
    let mut row = E2eRow { period, ..E2eRow::default() };
    // A fixed name: JACK frees a killed server's slot (8 per machine) only on a restart of
    // the same name.
    let server = "bass-bench".to_string();
    let jackd = Command::new("jackd")
        .args(["-n", &server, "-d", "dummy", "-r", "48000", "-C", "2", "-P", "2", "-p"])
        .arg(period.to_string())
        .env("JACK_NO_AUDIO_RESERVATION", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn();
    let jackd = match jackd {
        Ok(c) => Proc(c),
        Err(e) => {
            row.skipped = Some(format!("jackd: {e}"));
            return row;
        }
    };
    std::env::set_var("JACK_DEFAULT_SERVER", &server);
    std::env::set_var("ALSA_CONFIG_PATH", dir.join("alsa.conf"));
    // Wait for the server to accept clients.
    let t = Instant::now();
    let jack = loop {
        match crate::jack::JackClient::start("bassbench") {
            Ok(c) => break Some(c),
            Err(e) if t.elapsed() > Duration::from_secs(5) => {
                row.skipped = Some(format!("JACK client: {e}"));
                break None;
            }
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    };
    let Some(jack) = jack else { return row };
    let name = format!("bench-e2e-{period}");
    let name = name.as_str();
    let d = match start_bassd(bassd, name, "bassjack", chunk, 200) {
        Ok(d) => d,
        Err(e) => {
            row.skipped = Some(e);
            return row;
        }
    };
    std::thread::sleep(Duration::from_millis(300));
    let (b0, j0, t0) = (cpu_ns(d.0.id()), cpu_ns(jackd.0.id()), Instant::now());
    jack.reset();
    match read_delays(name, Duration::from_secs_f64(secs)) {
        Ok((v, f)) => {
            row.bass_stamp = v.iter().map(|x| x.1).collect();
            let (starts, spread) = jack.cycle_starts_mono();
            row.clock_spread_ns = spread;
            // The chunk a reader just got was made available by the latest cycle that
            // started before the reader woke.
            row.bass = v
                .iter()
                .filter_map(|&(t, _)| {
                    let i = starts.partition_point(|&s| s <= t);
                    (i > 0).then(|| (t - starts[i - 1]) as f64)
                })
                .collect();
            row.flags = f;
        }
        Err(e) => row.skipped = Some(format!("reader: {e}")),
    }
    row.jack = jack.delays_ns();
    let wall = t0.elapsed().as_nanos() as f64;
    row.bassd_cpu = (cpu_ns(d.0.id()) - b0) as f64 / wall;
    row.jackd_cpu = (cpu_ns(jackd.0.id()).saturating_sub(j0)) as f64 / wall;
    drop(d);
    drop(jack);
    drop(jackd);
    std::env::remove_var("JACK_DEFAULT_SERVER");
    row
}

fn cpu_row(bassd: &Path, device: &str, chunk: u32, secs: f64) -> Result<CpuRow, String> {
    let name = format!("bench-cpu-{chunk}");
    let name = name.as_str();
    let chunks = (48000 * 2 / chunk).max(4);
    let d = start_bassd(bassd, name, device, chunk, chunks)?;
    let mut kids: Vec<Child> = spawn_ready(1, "cpu-reader", &[name.into(), "every".into()]);
    kids.extend(spawn_ready(1, "cpu-reader", &[name.into(), "second".into()]));
    std::thread::sleep(Duration::from_millis(300));
    let pids: Vec<u32> = kids.iter().map(|k| k.pid()).collect();
    let (b0, r0, w0, t0) = (cpu_ns(d.0.id()), cpu_ns(pids[0]), cpu_ns(pids[1]), Instant::now());
    std::thread::sleep(Duration::from_secs_f64(secs));
    let wall = t0.elapsed().as_nanos() as f64;
    let row_cpu = |a: u64, b: u64| (a.saturating_sub(b)) as f64 / wall;
    let (b1, r1, w1) = (cpu_ns(d.0.id()), cpu_ns(pids[0]), cpu_ns(pids[1]));
    let rss = crate::procs::rss_of(&d.0.id().to_string());
    drop(d);
    // The second reader (1 s blocks): its voluntary context switches = times it slept.
    let lines: Vec<Vec<String>> = kids.into_iter().map(Child::finish).collect();
    let wakes =
        lines.get(1).and_then(|l| l.iter().find_map(|x| field(x, "sleeps_per_s"))).unwrap_or(f64::NAN);
    Ok(CpuRow {
        chunk,
        bassd: row_cpu(b1, b0),
        reader: row_cpu(r1, r0),
        waiter: row_cpu(w1, w0),
        waiter_wakes: wakes,
        bassd_rss: rss,
    })
}

/// Child: a reader of bassd's port; `every` reads every chunk, `second` waits for the frame
/// one second ahead each time (a 1 s block reader). Prints its wake-ups per second.
pub fn child_cpu_reader(args: &[String]) {
    let port = Port::open(&args[0]).expect("open port");
    let every = args[1] == "every";
    let rate = u64::from(port.geometry().sample_rate);
    let cap = rate as usize;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let (mut wakes, start) = (0u64, Instant::now());
    let sleeps0 = voluntary_switches();
    crate::procs::say_ready();
    loop {
        let target = if every { nfr } else { nfr + rate - 1 };
        match port.wait(target, Duration::from_secs(30)) {
            Ok(_) => {
                wakes += 1;
                let mut bufs = [&mut l[..], &mut r[..]];
                port.get_audio_data(cap, &mut nfr, &mut bufs).expect("read");
            }
            Err(_) => break,
        }
    }
    let secs = start.elapsed().as_secs_f64();
    println!(
        "wakes_per_s={} sleeps_per_s={}",
        wakes as f64 / secs,
        (voluntary_switches() - sleeps0) as f64 / secs
    );
}

/// Voluntary context switches of this process so far (each blocking wait is one).
fn voluntary_switches() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("voluntary_ctxt_switches:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(0)
}

/// Runs parts 4 and 5.
pub fn run(quick: bool) -> E2eResults {
    let secs = if quick { 2.0 } else { 6.0 };
    let mut res = E2eResults { seconds: secs, ..E2eResults::default() };
    let Some(bassd) = bassd_path() else {
        res.skipped = Some("bassd not built next to bass-bench (cargo build --release --workspace)".into());
        println!("  skipped: {}", res.skipped.as_deref().unwrap_or(""));
        return res;
    };
    for chunk in [32u32, 64, 256, 2205] {
        match cpu_row(&bassd, "sim:silence", chunk, secs) {
            Ok(c) => {
                println!(
                    "  bassd on sim:silence, 48 kHz stereo, {chunk:>4}-frame chunks: bassd {:.2}% of a core, RSS {} KiB; reader of every chunk {:.2}%; reader waiting 1 s blocks {:.3}% ({:.0} sleeps/s)",
                    c.bassd * 100.0,
                    c.bassd_rss.rss,
                    c.reader * 100.0,
                    c.waiter * 100.0,
                    c.waiter_wakes
                );
                res.cpu.push(c);
            }
            Err(e) => println!("  sim:silence {chunk}: {e}"),
        }
    }
    let dir = bassport::paths::runtime_dir();
    let conf = "</usr/share/alsa/alsa.conf>\npcm.bassjackraw {\n    type jack\n    capture_ports { 0 system:capture_1 1 system:capture_2 }\n}\npcm.bassjack {\n    type plug\n    slave.pcm \"bassjackraw\"\n}\n";
    if let Err(e) = std::fs::write(dir.join("alsa.conf"), conf) {
        res.skipped = Some(format!("write alsa.conf: {e}"));
        return res;
    }
    let have_jackd =
        Command::new("jackd").arg("--version").stdout(Stdio::null()).stderr(Stdio::null()).status().is_ok();
    for (period, chunk) in [(64u32, 64u32), (256, 256), (1024, 1024)] {
        let row = if have_jackd {
            e2e_row(&bassd, &dir, period, chunk, secs)
        } else {
            E2eRow {
                period,
                skipped: Some("jackd not installed (scripts/install-deps.sh)".into()),
                ..E2eRow::default()
            }
        };
        match &row.skipped {
            Some(why) if row.bass.is_empty() => println!("  end to end, period {period}: skipped: {why}"),
            _ => println!(
                "  end to end, JACK period {period}, bass chunk {chunk}: from cycle start: bass reader median {} p99 {} ({} chunks) | direct JACK client median {} p99 {} ({} periods) | ratio {:.2} | reader − chunk timestamp median {} (flags {:#x}) | bassd {:.2}% jackd {:.2}% of a core",
                fmt_ns(median(&row.bass)),
                fmt_ns(quantile(&row.bass, 0.99)),
                row.bass.len(),
                fmt_ns(median(&row.jack)),
                fmt_ns(quantile(&row.jack, 0.99)),
                row.jack.len(),
                median(&row.bass) / median(&row.jack),
                fmt_ns(median(&row.bass_stamp)),
                row.flags,
                row.bassd_cpu * 100.0,
                row.jackd_cpu * 100.0
            ),
        }
        res.e2e.push(row);
    }
    res
}
