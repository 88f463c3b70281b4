//! Part 7: bass against PipeWire, side by side in one run.
//!
//! - **PipeWire** (Debian's 0.3.x daemon): `pipewire -c bench.conf` (bench/pipewire/bench.conf)
//!   in a private runtime directory (`XDG_RUNTIME_DIR` = `PIPEWIRE_RUNTIME_DIR` = a scratch
//!   directory), no session manager, no devices, no realtime module; the Dummy-Driver (a timerfd)
//!   drives the graph at a fixed quantum of 256 frames at 48 kHz. A virtual source node
//!   (`bench-source`, zeros) in the driver's group is the capture "device"; N capture clients
//!   (bench/pipewire/pw-capture-client.c, compiled here against libpipewire with
//!   `-Wall -Wextra -Wpedantic -Werror`; a `pw_stream` each, RT_PROCESS) are linked to it with
//!   `pw-link`, since no session manager does it. Each records per cycle CLOCK_MONOTONIC on entry
//!   to its process callback and the cycle's `clock.nsec`, the Dummy-Driver's timer target.
//! - **bass**: `bassd --acquire sim:pattern --rate 48000 --frames 256 --rt-priority 0`; N reader
//!   processes (`child pw-cmp-reader`) blocked in `Port::wait`, each recording per wake-up
//!   CLOCK_MONOTONIC when `wait` returns and the due time of the newest chunk: its first frame's
//!   stamp (`mono_ns`, the simulated device's exact due time) + one chunk = the time the capture
//!   thread's pacing sleep was set to end, i.e. the timer target. Then it reads the chunk.
//! - delay = client awake − timer target, the same definition on both sides, on one clock.
//! - missed cycles: PipeWire, cycles a client's callback did not run for (its clock position
//!   jumped by more than one quantum); bass, chunks a reader did not wake for (two or more new
//!   at one wake-up) plus chunks lost (overwritten before they were read).
//! - CPU: on-CPU time of all threads of the daemon and of the clients
//!   (/proc/PID/task/*/schedstat) over the measurement window, as a share of one core.
//! - the split: a *timer probe* thread in this process, running while each system is measured,
//!   sleeps a random 3–6 ms at a time with that system's timer (PipeWire: an absolute timerfd waited for in `poll`, as the
//!   Dummy-Driver's loop does; bass: bassd's own pacing (`basskit::pacing::sleep_until`) on a thread with the
//!   capture thread's timer slack) and records its wake-up − target: the *timer part*. The
//!   *dispatch part* (daemon awake → client awake) is the client delay's median minus it.
//!
//! Both are measured round by round, PipeWire then bass at 1, 8 and 64 clients, four times in a
//! full run (twice in a quick one), so both see the same machine; the delay goals compare each
//! bass round with the PipeWire round just before it and take the median of those ratios.
//! First without realtime scheduling on either side, then (full runs) with SCHED_FIFO on both.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use bassport::sys::monotonic_ns;
use bassport::{Error, Port, State};

use crate::e2e::{bassd_path, Proc};
use crate::procs::{field, Child};
use crate::stats::{fmt_ns, median, quantile};

pub use crate::workload::{CLIENTS, QUANTUM, RATE};

mod daemon;
mod probe;

use daemon::{pw_clients, tools, Daemon, Tools};
pub use daemon::{Sched, RT_CLIENT, RT_DAEMON};
use probe::{probe_bass_pacing, probe_timerfd, window};

/// One system (PipeWire or bass) at one client count in one round.
#[derive(Clone, Debug, Default)]
pub struct Round {
    /// Every client's delay per cycle (ns): client awake − the timer target.
    pub delays: Vec<f64>,
    /// Cycles in the window, per client (window / period).
    pub cycles: u64,
    /// Missed cycles, summed over the clients.
    pub missed: u64,
    /// bass only, of `missed`: chunks lost (overwritten before read), and wake-ups that found
    /// two or more new chunks one of which was flagged LATE (the broker fell behind: its
    /// pacing woke late, or its capture thread was held before the publish).
    pub lost: u64,
    /// See `lost`.
    pub broker_late: u64,
    /// The daemon's (pipewire / bassd) CPU, share of one core.
    pub daemon_cpu: f64,
    /// All clients' CPU together, share of one core.
    pub clients_cpu: f64,
    /// The timer probe: wake-up − target (ns), per wake-up.
    pub timer: Vec<f64>,
}

impl Round {
    /// Median delay.
    pub fn p50(&self) -> f64 {
        median(&self.delays)
    }

    /// 99th percentile of the delay.
    pub fn p99(&self) -> f64 {
        quantile(&self.delays, 0.99)
    }

    /// Daemon + clients, share of one core.
    pub fn cpu(&self) -> f64 {
        self.daemon_cpu + self.clients_cpu
    }
}

/// Both systems at one client count: one [`Round`] each per round.
#[derive(Clone, Debug, Default)]
pub struct Side {
    /// PipeWire, per round.
    pub pw: Vec<Round>,
    /// bass, per round.
    pub bass: Vec<Round>,
}

/// Pools the rounds' delays (or timer samples) of one system.
pub fn pooled(rounds: &[Round], f: impl Fn(&Round) -> &Vec<f64>) -> Vec<f64> {
    rounds.iter().flat_map(|r| f(r).iter().copied()).collect()
}

/// One comparison (one scheduling) at every client count.
#[derive(Clone, Debug, Default)]
pub struct Comparison {
    /// Scheduling of both sides.
    pub sched: Sched,
    /// Per client count.
    pub sides: BTreeMap<usize, Side>,
    /// What the threads really ran with (checked in /proc while measuring).
    pub checked: String,
}

/// Results of part 7.
#[derive(Clone, Debug, Default)]
pub struct PwResults {
    /// Without realtime scheduling, then (where the machine allows it) with.
    pub runs: Vec<Comparison>,
    /// Seconds measured per system, client count and round.
    pub seconds: f64,
    /// "PipeWire 0.3.65", from `pipewire --version`.
    pub pw_version: String,
    /// Whether the realtime comparison ran, and why not if not.
    pub realtime: String,
    /// Why the part did not run, if so.
    pub skipped: Option<String>,
    /// bass callback streams vs JACK process callbacks ([`crate::callbacks`]).
    pub callbacks: Option<crate::callbacks::CallbackResults>,
}

/// Delays and missed cycles of one PipeWire client from its lines `ENTERED TARGET TICKS`,
/// keeping the cycles entered inside `window` (CLOCK_MONOTONIC ns). A cycle whose clock
/// position is more than one quantum after the previous one's means cycles the client missed.
pub fn pw_client(lines: &[String], window: (u64, u64), quantum: u64) -> (Vec<f64>, u64) {
    let (mut delays, mut missed, mut prev) = (Vec::new(), 0u64, None::<u64>);
    for l in lines {
        let v: Vec<u64> = l.split_whitespace().filter_map(|x| x.parse().ok()).collect();
        let [entered, target, ticks] = v[..] else { continue };
        if entered < window.0 || entered > window.1 || target == 0 {
            prev = Some(ticks);
            continue;
        }
        if let Some(p) = prev {
            missed += (ticks.saturating_sub(p) / quantum.max(1)).saturating_sub(1);
        }
        prev = Some(ticks);
        delays.push(entered.saturating_sub(target) as f64);
    }
    (delays, missed)
}

/// What one bass reader saw (see [`bass_reader`]).
#[derive(Debug, Default, PartialEq)]
pub struct ReaderStats {
    /// Delays (ns).
    pub delays: Vec<f64>,
    /// Chunks it did not wake for, or lost.
    pub missed: u64,
    /// Of them, lost chunks.
    pub lost: u64,
    /// Wake-ups with two or more new chunks one of which was flagged LATE.
    pub broker_late: u64,
}

/// Delays and missed chunks of one bass reader from its lines `WOKE DUE NEW LOST FLAGS` (woken
/// at, the newest chunk's due time, chunks new at this wake-up, frames lost, the new chunks'
/// flags, or-ed), keeping the wake-ups inside `window`. Missed: chunks beyond the first at one
/// wake-up, and lost chunks.
pub fn bass_reader(lines: &[String], window: (u64, u64), nfpc: u64) -> ReaderStats {
    let mut r = ReaderStats::default();
    for l in lines {
        let v: Vec<u64> = l.split_whitespace().filter_map(|x| x.parse().ok()).collect();
        let [woke, due, new, lost, flags] = v[..] else { continue };
        if woke < window.0 || woke > window.1 || due == 0 {
            continue;
        }
        let lost = lost.div_ceil(nfpc.max(1));
        r.missed += new.saturating_sub(1) + lost;
        r.lost += lost;
        if new > 1 && flags & u64::from(bassport::format::chunk_flags::LATE) != 0 {
            r.broker_late += 1;
        }
        r.delays.push(woke.saturating_sub(due) as f64);
    }
    r
}

/// The chunk / quantum period in ns.
fn period_ns() -> u64 {
    u64::from(QUANTUM) * 1_000_000_000 / u64::from(RATE)
}

/// One PipeWire round with `n` clients.
fn pw_round(t: &Tools, dir: &Path, n: usize, sched: Sched, secs: f64) -> Result<(Round, String), String> {
    let d = Daemon::start(dir, sched)?;
    let kids = pw_clients(t, &d, n)?;
    std::thread::sleep(Duration::from_millis(300));
    let pids: Vec<u32> = kids.iter().map(Child::pid).collect();
    let checked = format!("pipewire {}, clients {}", fifo_threads(&[d.proc.0.id()]), fifo_threads(&pids));
    let (win, daemon_cpu, clients_cpu, timer) = window(d.proc.0.id(), &pids, secs, sched, probe_timerfd);
    let mut r =
        Round { daemon_cpu, clients_cpu, timer, cycles: (win.1 - win.0) / period_ns(), ..Round::default() };
    for k in kids {
        // SAFETY: signalling our own child by its pid; it prints its table and exits.
        unsafe { libc::kill(k.pid() as libc::pid_t, libc::SIGINT) };
        let lines = k.finish();
        if let Some(dropped) = lines.iter().find_map(|l| field(l, "dropped")).filter(|&x| x > 0.0) {
            println!("  (a PipeWire client's table was full: {dropped} cycles not recorded)");
        }
        let (delays, missed) = pw_client(&lines, win, u64::from(QUANTUM));
        r.delays.extend(delays);
        r.missed += missed;
    }
    drop(d);
    Ok((r, checked))
}

/// One bass round with `n` readers.
fn bass_round(
    bassd: &Path,
    n: usize,
    rep: usize,
    sched: Sched,
    secs: f64,
) -> Result<(Round, String), String> {
    // A fresh broker name per round: no port left over from the last round to take over.
    let name = format!("bench-pw-cmp-{n}-{rep}-{}", sched as u8);
    let name = name.as_str();
    let chunks = (RATE * 2 / QUANTUM).to_string();
    let child = Command::new(bassd)
        .args(["--name", name, "--rt-priority", if sched == Sched::Fifo { "70" } else { "0" }])
        .args(["--acquire", "sim:pattern", "--rate"])
        .arg(RATE.to_string())
        .args(["--frames", &QUANTUM.to_string(), "--chunks", &chunks])
        .env("BASS_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .map_err(|e| format!("start bassd: {e}"))?;
    let d = Proc(child);
    let t = Instant::now();
    while !Port::open(name)
        .map(|p| p.info().map(|i| i.state == Some(State::Capturing)).unwrap_or(false))
        .unwrap_or(false)
    {
        if t.elapsed() > Duration::from_secs(10) {
            return Err("bassd did not start capturing sim:pattern within 10 s".into());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let prio = if sched == Sched::Fifo { RT_CLIENT } else { 0 };
    let kids = crate::procs::spawn_ready(n, "pw-cmp-reader", &[name.to_owned(), prio.to_string()]);
    std::thread::sleep(Duration::from_millis(300));
    let pids: Vec<u32> = kids.iter().map(Child::pid).collect();
    let checked = format!("bassd {}, readers {}", fifo_threads(&[d.0.id()]), fifo_threads(&pids));
    let (win, daemon_cpu, clients_cpu, timer) = window(d.0.id(), &pids, secs, sched, probe_bass_pacing);
    drop(d);
    let mut r =
        Round { daemon_cpu, clients_cpu, timer, cycles: (win.1 - win.0) / period_ns(), ..Round::default() };
    for k in kids {
        let st = bass_reader(&k.finish(), win, u64::from(QUANTUM));
        r.delays.extend(st.delays);
        r.missed += st.missed;
        r.lost += st.lost;
        r.broker_late += st.broker_late;
    }
    Ok((r, checked))
}

/// "K of M threads SCHED_FIFO" over the threads of `pids` (/proc/PID/task/TID/stat, field 41).
fn fifo_threads(pids: &[u32]) -> String {
    let (mut fifo, mut all) = (0, 0);
    for pid in pids {
        let Ok(dir) = std::fs::read_dir(format!("/proc/{pid}/task")) else { continue };
        for e in dir.flatten() {
            let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else { continue };
            // Fields after the command (which may hold spaces) start at field 3.
            let rest = stat.rsplit_once(')').map_or("", |x| x.1);
            all += 1;
            if rest.split_whitespace().nth(38).and_then(|p| p.parse::<u32>().ok()) == Some(1) {
                fifo += 1;
            }
        }
    }
    format!("{fifo} of {all} threads SCHED_FIFO")
}

/// Puts the calling thread in SCHED_FIFO at `prio`.
fn set_fifo(prio: i32) -> Result<(), String> {
    bassport::sys::sched::set_fifo(prio).map_err(|e| std::io::Error::from_raw_os_error(e).to_string())
}

/// Whether this process may use SCHED_FIFO (tried on a short-lived thread).
fn realtime_allowed() -> Result<(), String> {
    std::thread::spawn(|| set_fifo(1)).join().unwrap_or_else(|_| Err("thread panicked".into()))
}

/// Child: a reader of bassd's port for part 7 (`PORT [FIFO_PRIORITY]`); prints
/// `WOKE DUE NEW LOST FLAGS` per wake-up (see [`bass_reader`]) once the port stops.
pub fn child_reader(args: &[String]) {
    let port = Port::open(&args[0]).expect("open port");
    let prio: i32 = args.get(1).and_then(|p| p.parse().ok()).unwrap_or(0);
    if prio > 0 {
        set_fifo(prio).unwrap_or_else(|e| panic!("SCHED_FIFO {prio} refused: {e}"));
    }
    let g = port.geometry();
    let nfpc = u64::from(g.frames_per_chunk);
    let chunk_ns = nfpc * 1_000_000_000 / u64::from(g.sample_rate);
    let cap = nfpc as usize * 8;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let mut rec: Vec<[u64; 5]> = Vec::with_capacity(1 << 16);
    crate::procs::say_ready();
    let mut last = nfr - 1;
    loop {
        match port.wait(nfr, Duration::from_secs(30)) {
            Ok(lfi) => {
                let woke = monotonic_ns();
                let newest = (lfi - 1) / nfpc * nfpc + 1;
                let (due, mut flags) =
                    port.chunk_info(newest).map(|c| (c.mono_ns + chunk_ns, c.flags)).unwrap_or((0, 0));
                let mut bufs = [&mut l[..], &mut r[..]];
                let got = port.get_audio_data(cap, &mut nfr, &mut bufs).expect("read");
                let new = (lfi / nfpc).saturating_sub(last / nfpc);
                last = lfi;
                // Every new chunk's flags, not only the newest's: a chunk held in the broker
                // is the older of the two a late wake-up finds.
                for k in 1..new.min(8) {
                    flags |= port.chunk_info(newest.saturating_sub(k * nfpc).max(1)).map_or(0, |c| c.flags);
                }
                if rec.len() < rec.capacity() {
                    rec.push([woke, due, new, got.loss, u64::from(flags)]);
                }
            }
            Err(Error::Stopped { .. }) => break,
            Err(e) => panic!("pw-cmp reader: {e}"),
        }
    }
    let mut out = String::with_capacity(rec.len() * 48);
    for [a, b, c, d, e] in &rec {
        out.push_str(&format!("{a} {b} {c} {d} {e}\n"));
    }
    print!("{out}");
}

/// Prints one round of one system.
fn say(what: &str, rep: usize, n: usize, r: &Round) {
    println!(
        "  round {} {what:<8} {n:>2} client{}: delay p50 {} p99 {} ({} samples, {} missed (lost {}, broker late {}) of {} cycles × {n}) | timer part p50 {} | CPU daemon {:.2} % + clients {:.2} % of a core",
        rep + 1,
        if n == 1 { "" } else { "s" },
        fmt_ns(r.p50()),
        fmt_ns(r.p99()),
        r.delays.len(),
        r.missed,
        r.lost,
        r.broker_late,
        r.cycles,
        fmt_ns(median(&r.timer)),
        r.daemon_cpu * 100.0,
        r.clients_cpu * 100.0
    );
}

/// Runs part 7: `rounds` rounds of `secs` seconds per system and client count, without
/// realtime scheduling and then, if `realtime` and the machine allows it, with.
pub fn run(rounds: usize, secs: f64, realtime: bool) -> PwResults {
    let mut res = PwResults { seconds: secs, ..PwResults::default() };
    let Some(bassd) = bassd_path() else {
        res.skipped = Some("bassd not built next to bass-bench".into());
        return res;
    };
    let scratch = std::env::temp_dir().join(format!("bass-bench-pw.{}", std::process::id()));
    let _ = std::fs::create_dir_all(&scratch);
    let t = match tools(&scratch) {
        Ok(t) => t,
        Err(e) => {
            println!("  PipeWire comparison skipped: {e}");
            res.skipped = Some(e);
            let _ = std::fs::remove_dir_all(&scratch);
            return res;
        }
    };
    res.pw_version = t.version.clone();
    let mut scheds = vec![Sched::Normal];
    res.realtime = match (realtime, realtime_allowed()) {
        (false, _) => "not run (quick mode)".into(),
        (true, Err(e)) => format!("not run: SCHED_FIFO refused here ({e})"),
        (true, Ok(())) => {
            scheds.push(Sched::Fifo);
            format!("SCHED_FIFO allowed here: run with the daemons' threads at {RT_DAEMON} and the clients' at {RT_CLIENT}")
        }
    };
    'all: for sched in scheds {
        let mut cmp = Comparison { sched, ..Comparison::default() };
        let mut checked = Vec::new();
        println!(
            "  {}",
            if sched == Sched::Fifo { "with SCHED_FIFO:" } else { "without realtime scheduling:" }
        );
        for rep in 0..rounds {
            for &n in CLIENTS {
                let (pw, c1) = match pw_round(&t, &scratch.join("run"), n, sched, secs) {
                    Ok(r) => r,
                    Err(e) => {
                        println!("  PipeWire round failed: {e}");
                        res.skipped = Some(e);
                        break 'all;
                    }
                };
                say("PipeWire", rep, n, &pw);
                let (bass, c2) = match bass_round(&bassd, n, rep, sched, secs) {
                    Ok(r) => r,
                    Err(e) => {
                        println!("  bass round failed: {e}");
                        res.skipped = Some(e);
                        break 'all;
                    }
                };
                say("bass", rep, n, &bass);
                if rep == 0 {
                    checked.push(format!("{n} client{}: {c1}; {c2}", if n == 1 { "" } else { "s" }));
                }
                let side = cmp.sides.entry(n).or_default();
                side.pw.push(pw);
                side.bass.push(bass);
            }
        }
        cmp.checked = checked.join("; ");
        println!("  threads: {}", cmp.checked);
        res.runs.push(cmp);
    }
    let _ = std::fs::remove_dir_all(&scratch);
    println!("  callback APIs: bass callback streams vs JACK process callbacks (no realtime scheduling):");
    res.callbacks = Some(crate::callbacks::run(&bassd, secs));
    res
}

#[cfg(test)]
mod tests {
    use super::daemon::{CLIENT_C, CONF};
    use super::*;

    fn lines(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn pw_client_delays_are_entry_minus_target_and_position_jumps_are_missed_cycles() {
        let l = lines(&[
            "ready",
            "900 800 0",      // before the window: not counted, but its position is the reference
            "1100 1000 256",  // 100 ns
            "1350 1200 512",  // 150 ns
            "2000 1900 1280", // 1280 - 512 = 3 quanta: 2 missed
            "2100 0 1536",    // no clock: skipped
            "9000 8000 1792", // after the window
            "cycles=6 dropped=0",
        ]);
        let (d, missed) = pw_client(&l, (1000, 5000), 256);
        assert_eq!(d, vec![100.0, 150.0, 100.0]);
        assert_eq!(missed, 2);
    }

    #[test]
    fn bass_reader_counts_skipped_wakes_lost_chunks_and_late_publishes() {
        let l = lines(&[
            "1100 1000 1 0 0",   // 100 ns
            "1300 1050 2 0 8",   // 250 ns, woke once for 2 chunks, the newest LATE: 1 missed
            "1500 1400 1 300 0", // 300 lost frames = 2 chunks of 256
            "1700 1600 3 0 0",   // 2 missed, the broker was on time
            "50 10 5 0 8",       // before the window
            "1800 1700 1 0",     // malformed: skipped
        ]);
        let r = bass_reader(&l, (1000, 5000), 256);
        assert_eq!(r.delays, vec![100.0, 250.0, 100.0, 100.0]);
        assert_eq!((r.missed, r.lost, r.broker_late), (5, 2, 1));
    }

    #[test]
    fn the_client_source_and_the_configuration_are_what_the_part_describes() {
        // The driver at the fixed quantum, no realtime module unless asked, the source node
        // the clients are linked to; the client's stream flags and its output protocol.
        for key in [
            "factory.name = support.node.driver",
            "node.name = Dummy-Driver",
            "default.clock.quantum = 256",
            "default.clock.min-quantum = 256",
            "default.clock.max-quantum = 256",
            "default.clock.rate = 48000",
            "node.name = bench-source",
            "@RT_MODULE@",
        ] {
            assert!(CONF.contains(key), "bench.conf lacks {key}");
        }
        assert!(!CONF.replace("@RT_MODULE@", "").contains("module-rt"));
        for key in [
            "PW_STREAM_FLAG_AUTOCONNECT",
            "PW_STREAM_FLAG_MAP_BUFFERS",
            "PW_STREAM_FLAG_RT_PROCESS",
            "pw_stream_get_time_n",
            "\"ready\\n\"",
        ] {
            assert!(CLIENT_C.contains(key), "pw-capture-client.c lacks {key}");
        }
    }
}
