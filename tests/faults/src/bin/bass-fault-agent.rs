//! The fault agent: the child processes of the fault suite (a pattern writer, pattern readers
//! of several kinds, victims to kill, a process that tries to write through a reader's
//! mapping, a reader hammered while its port shrinks). Tests start it, stop it, kill it and
//! read its `ready` / `READ` / `RESULT` lines.
//!
//! ```text
//! bass-fault-agent writer  --port P [--channels 2 --nfpc 64 --ncop 8 --rate 48000]
//!                          [--pace-us U] [--chunks K | --seconds S] [--wait-go]
//! bass-fault-agent reader  --port P --mode copy|wait|view --n N [--pause-us U] [--log-loss]
//! bass-fault-agent stepped --port P --n N          (one read per "read" line on stdin)
//! bass-fault-agent victim  --port P --mode read|wait
//! bass-fault-agent poke    --port P                (writes through its read-only mapping)
//! bass-fault-agent shrink-victim --port P          (library calls until stdin closes)
//! bass-fault-agent try-open --port P               (reports whether it may open / write)
//! bass-fault-agent try-open --name N               (opens by name: a memfd port through the broker)
//! bass-fault-agent control-victim --socket S --name N  (status requests forever)
//! bass-fault-agent follow --port P --n N --expect zero|pattern  (across epochs, until stdin closes)
//! bass-fault-agent hold-connections --socket S --name N --n K  (holds them until stdin closes)
//! bass-fault-agent pin-loop --socket S --name N [--device D --rate R --nfpc F --ncop C
//!                           --channels CH] --rounds K  (Acquire and keep each new port mapped)
//! ```
//!
//! Wherever a port is read, `--fd N` (an inherited descriptor, e.g. of a memfd port) or
//! `--name N` (`Port::open`, in $BASS_RUNTIME_DIR) may stand for `--port P`.
//!
//! Arguments are parsed with clap (`bass-fault-agent ROLE --help`); a bad value is an error
//! naming the option, exit status 2. Output lines go through `say!`: if the test stops
//! reading, the agent ends quietly with status 0 instead of panicking on EPIPE.

use std::fmt;
use std::io::{BufRead, ErrorKind, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use bass_faults::count_corrupted;
use bassclient::testsignal::{fill_pattern_interleaved, pattern_expected};
use bassclient::{ChunkMeta, Error, Geometry, Port, PortParams, Source, State, Writer};
use clap::{Args, Parser, Subcommand, ValueEnum};

/// The child processes of the bass fault suite.
#[derive(Parser)]
#[command(name = "bass-fault-agent")]
struct Cli {
    #[command(subcommand)]
    role: Role,
}

#[derive(Subcommand)]
enum Role {
    /// Publish the pattern signal into a new port.
    Writer(WriterArgs),
    /// Read the pattern until the writer stops; report the accounting.
    Reader(ReaderArgs),
    /// One read per `read` line on stdin, reported as a `READ` line.
    Stepped(SteppedArgs),
    /// Read or wait forever, to be killed mid-call.
    Victim(VictimArgs),
    /// Store through the read-only mapping (must fault).
    Poke(PortArg),
    /// Call every size-dependent library function until stdin closes.
    ShrinkVictim(PortArg),
    /// Report whether this process may open the port for reading and for writing.
    TryOpen(PortArg),
    /// Send status requests forever, to be killed mid-request.
    ControlVictim(BrokerArgs),
    /// Follow the port across acquisitions until stdin closes.
    Follow(FollowArgs),
    /// Open control connections and hold the served ones until stdin closes.
    HoldConnections(HoldArgs),
    /// Acquire and keep each new port mapped, round after round.
    PinLoop(PinArgs),
}

#[derive(Args)]
#[group(required = true, multiple = false)]
struct PortArg {
    /// The port file.
    #[arg(long)]
    port: Option<PathBuf>,
    /// An inherited descriptor of the port (close-on-exec cleared), e.g. of a memfd port.
    #[arg(long)]
    fd: Option<i32>,
    /// A port name, opened with `Port::open` (a memfd port through its broker).
    #[arg(long)]
    name: Option<String>,
}

impl PortArg {
    /// The port file, for the roles that need a path.
    fn path(&self) -> &Path {
        self.port.as_deref().unwrap_or_else(|| {
            eprintln!("bass-fault-agent: this role needs --port PATH");
            std::process::exit(2)
        })
    }
}

#[derive(Args)]
struct WriterArgs {
    #[command(flatten)]
    port: PortArg,
    #[arg(long, default_value_t = 2)]
    channels: u32,
    #[arg(long, default_value_t = 48000)]
    rate: u32,
    /// Frames per chunk.
    #[arg(long, default_value_t = 64)]
    nfpc: u32,
    /// Chunks on the port.
    #[arg(long, default_value_t = 8)]
    ncop: u32,
    /// One chunk every U µs on absolute deadlines (0: unpaced; at most an hour).
    #[arg(long = "pace-us", default_value_t = 0,
          value_parser = clap::value_parser!(u64).range(..=3_600_000_000))]
    pace_us: u64,
    /// Stop after K chunks (0: no limit).
    #[arg(long, default_value_t = 0)]
    chunks: u64,
    /// Stop after S seconds (0: no limit).
    #[arg(long, default_value_t = 0)]
    seconds: u64,
    /// After `ready`, wait for a line on stdin before publishing.
    #[arg(long = "wait-go")]
    wait_go: bool,
    /// Group that may read the port.
    #[arg(long)]
    group: Option<u32>,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ReadMode {
    /// bass_get_audio_data into the reader's buffers.
    Copy,
    /// Block in wait until the frames are published, then copy.
    Wait,
    /// Zero-copy view, read in place.
    View,
}

#[derive(Args)]
struct ReaderArgs {
    #[command(flatten)]
    port: PortArg,
    #[arg(long, value_enum, default_value_t = ReadMode::Copy)]
    mode: ReadMode,
    /// Frames per read.
    #[arg(long, default_value_t = 64)]
    n: usize,
    /// Pause between reads, µs.
    #[arg(long = "pause-us", default_value_t = 0)]
    pause_us: u64,
    /// Print a `LOSS` line for every read that lost frames.
    #[arg(long = "log-loss")]
    log_loss: bool,
}

#[derive(Args)]
struct SteppedArgs {
    #[command(flatten)]
    port: PortArg,
    /// Frames per read.
    #[arg(long, default_value_t = 1 << 20)]
    n: usize,
    /// The first frame to read.
    #[arg(long, default_value_t = 1)]
    nfr: u64,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum VictimMode {
    /// Read the whole window in a loop.
    Read,
    /// Wait for a frame that never comes.
    Wait,
}

#[derive(Args)]
struct VictimArgs {
    #[command(flatten)]
    port: PortArg,
    #[arg(long, value_enum, default_value_t = VictimMode::Read)]
    mode: VictimMode,
}

#[derive(Args)]
struct BrokerArgs {
    /// The broker's control socket.
    #[arg(long)]
    socket: PathBuf,
    /// The broker's name.
    #[arg(long, default_value = "default")]
    name: String,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Expect {
    /// Silence: every sample 0.
    Zero,
    /// The test pattern.
    Pattern,
}

#[derive(Args)]
struct FollowArgs {
    #[command(flatten)]
    port: PortArg,
    /// Frames per read.
    #[arg(long, default_value_t = 480)]
    n: usize,
    #[arg(long, value_enum, default_value_t = Expect::Zero)]
    expect: Expect,
}

#[derive(Args)]
struct HoldArgs {
    #[command(flatten)]
    broker: BrokerArgs,
    /// Connections to open.
    #[arg(long, default_value_t = 1)]
    n: u64,
}

#[derive(Args)]
struct PinArgs {
    #[command(flatten)]
    broker: BrokerArgs,
    #[arg(long, default_value = "sim:silence")]
    device: String,
    #[arg(long, default_value_t = 48000)]
    rate: u32,
    #[arg(long, default_value_t = 480)]
    nfpc: u32,
    #[arg(long, default_value_t = 100)]
    ncop: u32,
    #[arg(long, default_value_t = 2)]
    channels: u32,
    /// Acquire-and-keep rounds.
    #[arg(long, default_value_t = 10)]
    rounds: u64,
}

fn main() {
    match Cli::parse().role {
        Role::Writer(a) => writer(&a),
        Role::Reader(a) => reader(&a),
        Role::Stepped(a) => stepped(&a),
        Role::Victim(a) => victim(&a),
        Role::Poke(a) => poke(&a),
        Role::ShrinkVictim(a) => shrink_victim(&a),
        Role::TryOpen(a) => try_open(&a),
        Role::ControlVictim(a) => control_victim(&a),
        Role::Follow(a) => follow(&a),
        Role::HoldConnections(a) => hold_connections(&a),
        Role::PinLoop(a) => pin_loop(&a),
    }
}

/// Prints one line for the test on stdout.
macro_rules! say {
    ($($arg:tt)*) => {
        say(format_args!($($arg)*))
    };
}

/// Writes `line` and a newline to stdout and flushes. A test that has stopped reading (the
/// pipe's read end is closed: EPIPE) leaves no one to report to, so the agent ends quietly
/// with status 0 rather than panicking; any other write error is status 1 with a message.
fn say(line: fmt::Arguments) {
    let mut out = std::io::stdout().lock();
    if let Err(e) = writeln!(out, "{line}").and_then(|()| out.flush()) {
        if e.kind() == ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("bass-fault-agent: writing to stdout: {e}");
        std::process::exit(1);
    }
}

/// A flag set when stdin reaches EOF or a "stop" line.
fn stdin_stop_flag() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    std::thread::spawn(move || {
        let stdin = std::io::stdin();
        let mut line = String::new();
        loop {
            line.clear();
            match stdin.lock().read_line(&mut line) {
                Ok(0) | Err(_) => break,
                Ok(_) if line.trim() == "stop" => break,
                Ok(_) => {}
            }
        }
        f.store(true, Ordering::Relaxed);
    });
    flag
}

fn monotonic() -> libc::timespec {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: valid out-pointer.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts
}

fn ts_ns(ts: &libc::timespec) -> i64 {
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

/// Publishes the pattern signal, paced on absolute deadlines or unpaced; reports how late
/// it ever was (a stalled or killed reader must not delay it).
fn writer(a: &WriterArgs) {
    let geometry = Geometry {
        channels: a.channels,
        sample_rate: a.rate,
        frames_per_chunk: a.nfpc,
        chunks_on_port: a.ncop,
    };
    let mut w = Writer::create_at(
        a.port.path(),
        &PortParams { geometry: geometry.clone(), device: "fault-agent".into(), group: a.group },
    )
    .expect("create port");
    say!("ready pid={} epoch={}", std::process::id(), w.epoch());
    let stop = if a.wait_go {
        let mut go = String::new();
        std::io::stdin().read_line(&mut go).expect("stdin");
        stdin_stop_flag()
    } else {
        stdin_stop_flag()
    };
    let (chunks, seconds) = (a.chunks, a.seconds);
    let pace_ns = a.pace_us as i64 * 1000; // at most 3.6e12: no overflow
    let started = Instant::now();
    let mut chunk = vec![0i32; (geometry.frames_per_chunk * geometry.channels) as usize];
    let mut deadline = monotonic();
    let (mut max_late_ns, mut max_publish_ns, mut published) = (0i64, 0u64, 0u64);
    let mut rss_start = 0;
    loop {
        if stop.load(Ordering::Relaxed)
            || (chunks > 0 && published >= chunks)
            || (seconds > 0 && started.elapsed() >= Duration::from_secs(seconds))
        {
            break;
        }
        if pace_ns > 0 {
            let t = ts_ns(&deadline) + pace_ns;
            deadline = libc::timespec { tv_sec: (t / 1_000_000_000) as _, tv_nsec: (t % 1_000_000_000) as _ };
            // SAFETY: valid timespec; absolute sleep on CLOCK_MONOTONIC.
            unsafe {
                libc::clock_nanosleep(
                    libc::CLOCK_MONOTONIC,
                    libc::TIMER_ABSTIME,
                    &deadline,
                    std::ptr::null_mut(),
                )
            };
            max_late_ns = max_late_ns.max(ts_ns(&monotonic()) - t);
        }
        fill_pattern_interleaved(&mut chunk, geometry.channels, w.last_frame_index() + 1);
        let t0 = Instant::now();
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).expect("publish");
        max_publish_ns = max_publish_ns.max(t0.elapsed().as_nanos() as u64);
        published += 1;
        if published == 1000 {
            rss_start = own_status_kb("VmRSS");
        }
    }
    let last = w.last_frame_index();
    w.stop();
    say!(
        "RESULT last={last} chunks={published} max_late_us={} max_publish_us={} rss_start_kb={rss_start} rss_end_kb={} anon_end_kb={} secs={:.3}",
        max_late_ns / 1000,
        max_publish_ns / 1000,
        own_status_kb("VmRSS"),
        own_status_kb("RssAnon"),
        started.elapsed().as_secs_f64()
    );
}

fn own_status_kb(field: &str) -> u64 {
    let text = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    text.lines()
        .find_map(|l| l.strip_prefix(field).and_then(|r| r.strip_prefix(':')))
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

fn open(a: &PortArg) -> Port {
    if let Some(fd) = a.fd {
        use std::os::fd::FromRawFd;
        // SAFETY: the test passed us this inherited descriptor (close-on-exec cleared) for us
        // alone; nothing else in this process owns or closes it.
        let owned = unsafe { std::os::fd::OwnedFd::from_raw_fd(fd) };
        return Port::from_fd(owned, "inherited").unwrap_or_else(|e| panic!("port from fd {fd}: {e}"));
    }
    if let Some(name) = &a.name {
        return Port::open(name).unwrap_or_else(|e| panic!("open port {name}: {e}"));
    }
    let path = a.path();
    let end = Instant::now() + Duration::from_secs(10);
    loop {
        match Port::open_path(path) {
            Ok(p) => return p,
            Err(Error::NotFound { .. } | Error::NotReady) if Instant::now() < end => {
                std::thread::sleep(Duration::from_millis(2))
            }
            Err(e) => panic!("open {}: {e}", path.display()),
        }
    }
}

/// Reads the pattern until the writer stops and every frame is accounted for; checks every
/// sample; prints delivered, lost, corrupted, requested (= frames covered) and whether the
/// last frame index ever went backwards.
fn reader(a: &ReaderArgs) {
    let port = open(&a.port);
    let (mode, n) = (a.mode, a.n);
    let pause = Duration::from_micros(a.pause_us);
    let log_loss = a.log_loss;
    let channels = port.geometry().channels as usize;
    let nfop = port.frames_on_port();
    let mut bufs = vec![vec![0i32; n.min(nfop as usize)]; channels];
    say!("ready pid={}", std::process::id());
    let (mut nfr, start) = (1u64, 1u64);
    let (mut delivered, mut lost, mut corrupted, mut reads, mut loss_events) = (0u64, 0u64, 0u64, 0u64, 0u64);
    let (mut last_lfi, mut regressions, mut max_loss, mut view_overwritten) = (0u64, 0u64, 0u64, 0u64);
    loop {
        if mode == ReadMode::Wait {
            match port.wait(nfr + n as u64 - 1, Duration::from_secs(60)) {
                Ok(_) | Err(Error::Stopped { .. }) => {}
                Err(e) => panic!("wait: {e}"),
            }
        }
        let info = port.info().expect("info");
        if info.last_frame_index < last_lfi {
            regressions += 1;
        }
        last_lfi = info.last_frame_index;
        let before = nfr;
        let (frames, loss) = if mode == ReadMode::View {
            let v = port.view(n, &mut nfr).expect("view");
            // Read in place (Relaxed atomic loads), then ask which frames may be overwritten.
            for (c, buf) in bufs.iter_mut().enumerate() {
                let ring = port.channel_ring(c).expect("channel");
                let (s0, l0) = v.segments[0];
                let (s1, l1) = v.segments[1];
                ring.copy_to(s0, &mut buf[..l0]);
                ring.copy_to(s1, &mut buf[l0..l0 + l1]);
            }
            let over = port.view_overwritten(&v) as usize;
            view_overwritten += over as u64;
            for buf in bufs.iter_mut() {
                buf.copy_within(over..v.frames, 0);
            }
            (v.frames - over, v.loss + over as u64)
        } else {
            let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
            let r = port.get_audio_data(n, &mut nfr, &mut outs).expect("get_audio_data");
            (r.frames, r.loss)
        };
        reads += 1;
        let first = before + loss;
        corrupted += count_corrupted(first, frames, &bufs);
        delivered += frames as u64;
        lost += loss;
        if loss > 0 {
            loss_events += 1;
            max_loss = max_loss.max(loss);
            if log_loss {
                let after = port.info().expect("info").last_frame_index;
                say!(
                    "LOSS nfr_before={before} loss={loss} n={frames} lfi_before={} lfi_after={after} nfop={nfop}",
                    info.last_frame_index
                );
            }
        }
        if frames == 0 && loss == 0 {
            let info = port.info().expect("info");
            if info.state == Some(State::Stopped) && nfr > info.last_frame_index {
                break;
            }
        }
        if !pause.is_zero() {
            std::thread::sleep(pause);
        }
    }
    say!(
        "RESULT delivered={delivered} lost={lost} corrupted={corrupted} requested={} reads={reads} loss_events={loss_events} max_loss={max_loss} lfi_regressions={regressions} view_overwritten={view_overwritten} rss_kb={}",
        nfr - start,
        own_status_kb("VmRSS")
    );
}

/// One read per "read" line on stdin, reported as a `READ` line.
fn stepped(a: &SteppedArgs) {
    let port = open(&a.port);
    let n = a.n;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; n.min(port.frames_on_port() as usize)]; channels];
    let mut nfr = a.nfr;
    say!("ready pid={}", std::process::id());
    let stdin = std::io::stdin();
    for line in stdin.lock().lines() {
        let line = line.expect("stdin");
        if line.trim() != "read" {
            break;
        }
        let lfi_before = port.info().expect("info").last_frame_index;
        let before = nfr;
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        let r = port.get_audio_data(n, &mut nfr, &mut outs).expect("get_audio_data");
        let lfi_after = port.info().expect("info").last_frame_index;
        let first = before + r.loss;
        let corrupted = count_corrupted(first, r.frames, &bufs);
        let stale = (0..r.frames).filter(|&i| bufs[0][i] != pattern_expected(first + i as u64, 0)).count();
        say!(
            "READ nfr_before={before} n={} loss={} nfr={nfr} first={first} corrupted={corrupted} stale={stale} lfi_before={lfi_before} lfi_after={lfi_after}",
            r.frames, r.loss
        );
    }
}

/// Opens the port and reads or waits forever, to be SIGKILLed mid-call.
fn victim(a: &VictimArgs) {
    let port = open(&a.port);
    let mode = a.mode;
    let nfop = port.frames_on_port() as usize;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; nfop]; channels];
    say!("ready pid={}", std::process::id());
    let mut nfr = 0u64;
    loop {
        if mode == VictimMode::Wait {
            let _ = port.wait(u64::MAX / 4, Duration::from_secs(3600));
        } else {
            let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
            let _ = port.get_audio_data(nfop, &mut nfr, &mut outs);
            nfr = nfr.saturating_sub(nfop as u64);
        }
    }
}

/// Reports how the port is open and mapped, then stores through the read-only mapping:
/// the store must fault (SIGSEGV). Prints SURVIVED and exits 0 if it did not.
fn poke(a: &PortArg) {
    let port = open(a);
    let path = std::fs::canonicalize(a.path()).expect("canonicalize");
    let p = path.to_string_lossy().into_owned();
    let maps = std::fs::read_to_string("/proc/self/maps").expect("maps");
    let perms: Vec<&str> = maps
        .lines()
        .filter(|l| l.ends_with(p.as_str()))
        .filter_map(|l| l.split_whitespace().nth(1))
        .collect();
    let mut flags = Vec::new();
    for e in std::fs::read_dir("/proc/self/fd").expect("fd dir").flatten() {
        if std::fs::read_link(e.path()).map(|t| t == path).unwrap_or(false) {
            let info =
                std::fs::read_to_string(format!("/proc/self/fdinfo/{}", e.file_name().to_string_lossy()))
                    .unwrap_or_default();
            if let Some(f) = info.lines().find_map(|l| l.strip_prefix("flags:")) {
                flags.push(f.trim().to_owned());
            }
        }
    }
    say!("MAPPING perms={} open_flags={}", perms.join(","), flags.join(","));
    let ring = port.channel_ring(0).expect("channel 0");
    ring.word_of(0).store(0x5a5a_5a5a_5a5a_5a5a, Ordering::Relaxed);
    say!("SURVIVED");
}

/// Calls every size-dependent library function in a loop until stdin closes, counting
/// outcomes; the test shrinks the file meanwhile. A SIGBUS would kill the process.
fn shrink_victim(a: &PortArg) {
    let port = open(a);
    let stop = stdin_stop_flag();
    let nfop = port.frames_on_port() as usize;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; nfop]; channels];
    say!("ready pid={}", std::process::id());
    let (mut ok, mut corrupt, mut other, mut calls) = (0u64, 0u64, 0u64, 0u64);
    let mut tally = |r: Result<(), Error>| match r {
        Ok(()) => ok += 1,
        Err(Error::Corrupt(_)) => corrupt += 1,
        Err(_) => other += 1,
    };
    while !stop.load(Ordering::Relaxed) {
        let mut nfr = 0u64;
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        tally(port.get_audio_data(nfop, &mut nfr, &mut outs).map(drop));
        tally(port.info().map(drop));
        tally(port.chunk_info(1).map(drop));
        tally(port.wait(1, Duration::ZERO).map(drop));
        let mut nfr = 0u64;
        tally(port.view(nfop, &mut nfr).map(drop));
        calls += 5;
    }
    // After a SIGBUS caught by the guard the handle stays unusable: a read of the restored
    // file still fails (a size-check Corrupt would pass once the size is back).
    let mut nfr = 0u64;
    let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
    if let Err(Error::Corrupt(m)) = port.get_audio_data(nfop, &mut nfr, &mut outs) {
        if m.contains("shrank under the reader") {
            say!("GUARDED {m}");
        }
    }
    say!("RESULT calls={calls} ok={ok} corrupt={corrupt} other={other}");
}

/// Reports whether this process (typically run under setpriv as another uid) can open the
/// port for reading through the library, and whether it could open the file for writing.
fn try_open(a: &PortArg) {
    if let Some(name) = &a.name {
        let read = match Port::open(name) {
            Ok(p) => format!(
                "ok lfi={} sealed={}",
                p.info().map(|i| i.last_frame_index).unwrap_or(0),
                p.size_sealed()
            ),
            Err(Error::NotFound { .. }) => "notfound".to_owned(),
            Err(e) => format!("error:{e}").replace(' ', "_"),
        };
        say!("RESULT uid={} read={read}", rustix::process::getuid().as_raw());
        return;
    }
    let port_path = a.path();
    let read = match Port::open_path(port_path) {
        Ok(p) => format!("ok lfi={}", p.info().map(|i| i.last_frame_index).unwrap_or(0)),
        Err(Error::Io { source, .. }) => format!("io:{}", source.raw_os_error().unwrap_or(0)),
        Err(e) => format!("error:{e}").replace(' ', "_"),
    };
    let write = match std::fs::OpenOptions::new().write(true).open(port_path) {
        Ok(_) => "ok".to_owned(),
        Err(e) => format!("io:{}", e.raw_os_error().unwrap_or(0)),
    };
    say!("RESULT uid={} read={read} write={write}", rustix::process::getuid().as_raw());
}

/// Opens `--n` control connections, asks each for the status, and holds the ones the broker
/// served until stdin closes; prints `held K refused R last_refusal=TEXT` first.
fn hold_connections(a: &HoldArgs) {
    let (socket, name) = (&a.broker.socket, &a.broker.name);
    let mut held = Vec::new();
    let (mut refused, mut last) = (0, String::new());
    for _ in 0..a.n {
        match bassclient::control::Client::connect_path(socket, name).and_then(|mut c| c.status().map(|_| c))
        {
            Ok(c) => held.push(c),
            Err(e) => {
                refused += 1;
                last = e.to_string().replace(' ', "_");
            }
        }
    }
    say!("held {} refused {refused} last_refusal={last}", held.len());
    let stop = stdin_stop_flag();
    while !stop.load(Ordering::Acquire) {
        std::thread::sleep(Duration::from_millis(20));
    }
    say!("RESULT held={} refused={refused}", held.len());
}

/// Connects to a broker's control socket and sends status requests forever, to be
/// SIGKILLed mid-request.
fn control_victim(a: &BrokerArgs) {
    let mut c = bassclient::control::Client::connect_path(&a.socket, &a.name).expect("connect");
    say!("ready pid={}", std::process::id());
    loop {
        let _ = c.status();
    }
}

/// Acquire, open the new port and keep it mapped, `--rounds` times; prints
/// one line per round (`ROUND i ok epoch=E` or `ROUND i refused ...`), then `RESULT` and
/// holds every mapping until stdin closes.
fn pin_loop(a: &PinArgs) {
    let mut c = bassclient::control::Client::connect_path(&a.broker.socket, &a.broker.name).expect("connect");
    let req = bassclient::control::AcquireRequest {
        device: a.device.clone(),
        sample_rate: a.rate,
        frames_per_chunk: a.nfpc,
        chunks_on_port: a.ncop,
        channels: a.channels,
        format: None,
    };
    let mut held = Vec::new();
    let (mut ok, mut refused) = (0, 0);
    for i in 0..a.rounds {
        match c.acquire(&req) {
            Ok(acq) => {
                ok += 1;
                held.push(Port::open_path(&acq.port).expect("open the new port"));
                say!("ROUND {i} ok epoch={}", acq.epoch);
            }
            Err(e) => {
                refused += 1;
                say!("ROUND {i} refused {}", e.to_string().replace('\n', " "));
            }
        }
    }
    say!("RESULT acquired={ok} refused={refused} held={}", held.len());
    let stop = stdin_stop_flag();
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(10));
    }
    drop(held);
}

fn mono_ns() -> u64 {
    ts_ns(&monotonic()) as u64
}

/// Follows the port by name across acquisitions until stdin closes: reads every block,
/// checks the content (`--expect zero` for silence, `pattern` for the test pattern), and
/// prints `DEVICE code=.. at_ns=..` when the acquisition ends on a device error and
/// `EPOCH e at_ns=..` for every port (epoch) it reads.
fn follow(a: &FollowArgs) {
    let path = a.port.path();
    let n = a.n;
    let expect_zero = a.expect == Expect::Zero;
    let stop = stdin_stop_flag();
    let port0 = open(&a.port);
    say!("ready pid={} epoch={}", std::process::id(), port0.epoch());
    drop(port0);
    let (mut delivered, mut lost, mut corrupted, mut epochs, mut errors) = (0u64, 0u64, 0u64, 0u64, 0u64);
    let mut last_epoch = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let port = match Port::open_path(path) {
            Ok(p) if p.epoch() != last_epoch => p,
            Ok(_) | Err(Error::NotFound { .. } | Error::NotReady) => {
                std::thread::sleep(Duration::from_millis(5));
                continue;
            }
            Err(e) => panic!("reopen: {e}"),
        };
        last_epoch = port.epoch();
        epochs += 1;
        say!("EPOCH {} at_ns={}", last_epoch, mono_ns());
        let mut bufs =
            vec![vec![0i32; n.min(port.frames_on_port() as usize)]; port.geometry().channels as usize];
        let mut nfr = 1u64;
        while !stop.load(Ordering::Relaxed) {
            match port.wait(nfr + n as u64 - 1, Duration::from_millis(500)) {
                Ok(_) | Err(Error::Timeout { .. }) => {}
                Err(Error::Device { code, message }) => {
                    errors += 1;
                    say!("DEVICE code={code} at_ns={} message={}", mono_ns(), message.replace(' ', "_"));
                    break;
                }
                Err(Error::Restarted | Error::Stopped { .. }) => break,
                Err(e) => panic!("wait: {e}"),
            }
            let before = nfr;
            let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
            let r = port.get_audio_data(n, &mut nfr, &mut outs).expect("get_audio_data");
            if expect_zero {
                corrupted += bufs
                    .iter()
                    .map(|b| b[..r.frames].iter().filter(|&&s| s != 0).count() as u64)
                    .sum::<u64>();
            } else {
                corrupted += count_corrupted(before + r.loss, r.frames, &bufs);
            }
            delivered += r.frames as u64;
            lost += r.loss;
        }
    }
    say!("RESULT delivered={delivered} lost={lost} corrupted={corrupted} epochs={epochs} device_errors={errors}");
}
