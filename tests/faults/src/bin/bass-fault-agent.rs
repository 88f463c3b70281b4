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
//!
//! Wherever a port is read, `--fd N` (an inherited descriptor, e.g. of a memfd port) or
//! `--name N` (`Port::open`, in $BASS_RUNTIME_DIR) may stand for `--port P`.
//! bass-fault-agent control-victim --socket S --name N  (status requests forever)
//! bass-fault-agent follow --port P --n N --expect zero|pattern  (across epochs, until stdin closes)
//! ```

use std::collections::HashMap;
use std::io::BufRead;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use bass_faults::count_corrupted;
use bassclient::testsignal::{fill_pattern_interleaved, pattern_expected};
use bassclient::{ChunkMeta, Error, Geometry, Port, PortParams, Source, State, Writer};

struct Args(HashMap<String, String>);

impl Args {
    fn parse(v: &[String]) -> Args {
        let mut m = HashMap::new();
        let mut i = 0;
        while i < v.len() {
            let k = v[i].trim_start_matches("--").to_owned();
            if i + 1 < v.len() && !v[i + 1].starts_with("--") {
                m.insert(k, v[i + 1].clone());
                i += 2;
            } else {
                m.insert(k, "1".into());
                i += 1;
            }
        }
        Args(m)
    }
    fn u(&self, k: &str, default: u64) -> u64 {
        self.0.get(k).map(|v| v.parse().unwrap_or_else(|_| panic!("--{k} {v}"))).unwrap_or(default)
    }
    fn s(&self, k: &str, default: &str) -> String {
        self.0.get(k).cloned().unwrap_or_else(|| default.to_owned())
    }
    fn flag(&self, k: &str) -> bool {
        self.0.contains_key(k)
    }
    fn port(&self) -> PathBuf {
        PathBuf::from(self.0.get("port").expect("--port PATH"))
    }
}

fn main() {
    let argv: Vec<String> = std::env::args().skip(1).collect();
    let role = argv.first().cloned().unwrap_or_default();
    let args = Args::parse(&argv[1.min(argv.len())..]);
    match role.as_str() {
        "writer" => writer(&args),
        "reader" => reader(&args),
        "stepped" => stepped(&args),
        "victim" => victim(&args),
        "poke" => poke(&args),
        "shrink-victim" => shrink_victim(&args),
        "try-open" => try_open(&args),
        "control-victim" => control_victim(&args),
        "follow" => follow(&args),
        "hold-connections" => hold_connections(&args),
        "pin-loop" => pin_loop(&args),
        _ => {
            eprintln!(
                "usage: bass-fault-agent writer|reader|stepped|victim|poke|shrink-victim --port PATH ..."
            );
            std::process::exit(2);
        }
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
fn writer(a: &Args) {
    let geometry = Geometry {
        channels: a.u("channels", 2) as u32,
        sample_rate: a.u("rate", 48000) as u32,
        frames_per_chunk: a.u("nfpc", 64) as u32,
        chunks_on_port: a.u("ncop", 8) as u32,
    };
    let group = a.0.get("group").map(|g| g.parse().expect("--group GID"));
    let mut w = Writer::create_at(
        &a.port(),
        &PortParams { geometry: geometry.clone(), device: "fault-agent".into(), group },
    )
    .expect("create port");
    println!("ready pid={} epoch={}", std::process::id(), w.epoch());
    let stop = if a.flag("wait-go") {
        let mut go = String::new();
        std::io::stdin().read_line(&mut go).expect("stdin");
        stdin_stop_flag()
    } else {
        stdin_stop_flag()
    };
    let chunks = a.u("chunks", 0);
    let seconds = a.u("seconds", 0);
    let pace_ns = a.u("pace-us", 0) as i64 * 1000;
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
    println!(
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

fn open(a: &Args) -> Port {
    if let Some(fd) = a.0.get("fd") {
        let fd: i32 = fd.parse().expect("--fd N");
        use std::os::fd::FromRawFd;
        // SAFETY: the test passed us this inherited descriptor (close-on-exec cleared) for us
        // alone; nothing else in this process owns or closes it.
        let owned = unsafe { std::os::fd::OwnedFd::from_raw_fd(fd) };
        return Port::from_fd(owned, "inherited").unwrap_or_else(|e| panic!("port from fd {fd}: {e}"));
    }
    if let Some(name) = a.0.get("name") {
        return Port::open(name).unwrap_or_else(|e| panic!("open port {name}: {e}"));
    }
    let path = a.port();
    let end = Instant::now() + Duration::from_secs(10);
    loop {
        match Port::open_path(&path) {
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
fn reader(a: &Args) {
    let port = open(a);
    let mode = a.s("mode", "copy");
    let n = a.u("n", 64) as usize;
    let pause = Duration::from_micros(a.u("pause-us", 0));
    let log_loss = a.flag("log-loss");
    let channels = port.geometry().channels as usize;
    let nfop = port.frames_on_port();
    let mut bufs = vec![vec![0i32; n.min(nfop as usize)]; channels];
    println!("ready pid={}", std::process::id());
    let (mut nfr, start) = (1u64, 1u64);
    let (mut delivered, mut lost, mut corrupted, mut reads, mut loss_events) = (0u64, 0u64, 0u64, 0u64, 0u64);
    let (mut last_lfi, mut regressions, mut max_loss, mut view_overwritten) = (0u64, 0u64, 0u64, 0u64);
    loop {
        if mode == "wait" {
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
        let (frames, loss) = if mode == "view" {
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
                println!(
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
    println!(
        "RESULT delivered={delivered} lost={lost} corrupted={corrupted} requested={} reads={reads} loss_events={loss_events} max_loss={max_loss} lfi_regressions={regressions} view_overwritten={view_overwritten} rss_kb={}",
        nfr - start,
        own_status_kb("VmRSS")
    );
}

/// One read per "read" line on stdin, reported as a `READ` line.
fn stepped(a: &Args) {
    let port = open(a);
    let n = a.u("n", 1 << 20) as usize;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; n.min(port.frames_on_port() as usize)]; channels];
    let mut nfr = a.u("nfr", 1);
    println!("ready pid={}", std::process::id());
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
        println!(
            "READ nfr_before={before} n={} loss={} nfr={nfr} first={first} corrupted={corrupted} stale={stale} lfi_before={lfi_before} lfi_after={lfi_after}",
            r.frames, r.loss
        );
    }
}

/// Opens the port and reads or waits forever, to be SIGKILLed mid-call.
fn victim(a: &Args) {
    let port = open(a);
    let mode = a.s("mode", "read");
    let nfop = port.frames_on_port() as usize;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; nfop]; channels];
    println!("ready pid={}", std::process::id());
    let mut nfr = 0u64;
    loop {
        if mode == "wait" {
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
fn poke(a: &Args) {
    let port = open(a);
    let path = std::fs::canonicalize(a.port()).expect("canonicalize");
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
    println!("MAPPING perms={} open_flags={}", perms.join(","), flags.join(","));
    let ring = port.channel_ring(0).expect("channel 0");
    ring.word_of(0).store(0x5a5a_5a5a_5a5a_5a5a, Ordering::Relaxed);
    println!("SURVIVED");
}

/// Calls every size-dependent library function in a loop until stdin closes, counting
/// outcomes; the test shrinks the file meanwhile. A SIGBUS would kill the process.
fn shrink_victim(a: &Args) {
    let port = open(a);
    let stop = stdin_stop_flag();
    let nfop = port.frames_on_port() as usize;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; nfop]; channels];
    println!("ready pid={}", std::process::id());
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
    println!("RESULT calls={calls} ok={ok} corrupt={corrupt} other={other}");
}

/// Reports whether this process (typically run under setpriv as another uid) can open the
/// port for reading through the library, and whether it could open the file for writing.
fn try_open(a: &Args) {
    if let Some(name) = a.0.get("name") {
        let read = match Port::open(name) {
            Ok(p) => format!(
                "ok lfi={} sealed={}",
                p.info().map(|i| i.last_frame_index).unwrap_or(0),
                p.size_sealed()
            ),
            Err(Error::NotFound { .. }) => "notfound".to_owned(),
            Err(e) => format!("error:{e}").replace(' ', "_"),
        };
        // SAFETY: getuid cannot fail.
        println!("RESULT uid={} read={read}", unsafe { libc::getuid() });
        return;
    }
    let read = match Port::open_path(&a.port()) {
        Ok(p) => format!("ok lfi={}", p.info().map(|i| i.last_frame_index).unwrap_or(0)),
        Err(Error::Io { source, .. }) => format!("io:{}", source.raw_os_error().unwrap_or(0)),
        Err(e) => format!("error:{e}").replace(' ', "_"),
    };
    let write = match std::fs::OpenOptions::new().write(true).open(a.port()) {
        Ok(_) => "ok".to_owned(),
        Err(e) => format!("io:{}", e.raw_os_error().unwrap_or(0)),
    };
    println!(
        "RESULT uid={} read={read} write={write}", // SAFETY: getuid cannot fail.
        unsafe { libc::getuid() }
    );
}

/// Opens `--n` control connections, asks each for the status, and holds the ones the broker
/// served until stdin closes; prints `held K refused R last_refusal=TEXT` first.
fn hold_connections(a: &Args) {
    let socket = PathBuf::from(a.s("socket", ""));
    let name = a.s("name", "default");
    let mut held = Vec::new();
    let (mut refused, mut last) = (0, String::new());
    for _ in 0..a.u("n", 1) {
        match bassclient::control::Client::connect_path(&socket, &name)
            .and_then(|mut c| c.status().map(|_| c))
        {
            Ok(c) => held.push(c),
            Err(e) => {
                refused += 1;
                last = e.to_string().replace(' ', "_");
            }
        }
    }
    println!("held {} refused {refused} last_refusal={last}", held.len());
    let stop = stdin_stop_flag();
    while !stop.load(Ordering::Acquire) {
        std::thread::sleep(Duration::from_millis(20));
    }
    println!("RESULT held={} refused={refused}", held.len());
}

/// Connects to a broker's control socket and sends status requests forever, to be
/// SIGKILLed mid-request.
fn control_victim(a: &Args) {
    let socket = PathBuf::from(a.s("socket", ""));
    let mut c = bassclient::control::Client::connect_path(&socket, &a.s("name", "default")).expect("connect");
    println!("ready pid={}", std::process::id());
    loop {
        let _ = c.status();
    }
}

/// Issue 14 item 4: Acquire, open the new port and keep it mapped, `--rounds` times; prints
/// one line per round (`ROUND i ok epoch=E` or `ROUND i refused ...`), then `RESULT` and
/// holds every mapping until stdin closes.
fn pin_loop(a: &Args) {
    let socket = PathBuf::from(a.s("socket", ""));
    let mut c = bassclient::control::Client::connect_path(&socket, &a.s("name", "default")).expect("connect");
    let req = bassclient::control::AcquireRequest {
        device: a.s("device", "sim:silence"),
        sample_rate: a.u("rate", 48000) as u32,
        frames_per_chunk: a.u("nfpc", 480) as u32,
        chunks_on_port: a.u("ncop", 100) as u32,
        channels: a.u("channels", 2) as u32,
        format: None,
    };
    let mut held = Vec::new();
    let (mut ok, mut refused) = (0, 0);
    for i in 0..a.u("rounds", 10) {
        match c.acquire(&req) {
            Ok(acq) => {
                ok += 1;
                held.push(Port::open_path(&acq.port).expect("open the new port"));
                println!("ROUND {i} ok epoch={}", acq.epoch);
            }
            Err(e) => {
                refused += 1;
                println!("ROUND {i} refused {}", e.to_string().replace('\n', " "));
            }
        }
    }
    println!("RESULT acquired={ok} refused={refused} held={}", held.len());
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
fn follow(a: &Args) {
    let path = a.port();
    let n = a.u("n", 480) as usize;
    let expect_zero = a.s("expect", "zero") == "zero";
    let stop = stdin_stop_flag();
    let port0 = open(a);
    println!("ready pid={} epoch={}", std::process::id(), port0.epoch());
    drop(port0);
    let (mut delivered, mut lost, mut corrupted, mut epochs, mut errors) = (0u64, 0u64, 0u64, 0u64, 0u64);
    let mut last_epoch = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let port = match Port::open_path(&path) {
            Ok(p) if p.epoch() != last_epoch => p,
            Ok(_) | Err(Error::NotFound { .. } | Error::NotReady) => {
                std::thread::sleep(Duration::from_millis(5));
                continue;
            }
            Err(e) => panic!("reopen: {e}"),
        };
        last_epoch = port.epoch();
        epochs += 1;
        println!("EPOCH {} at_ns={}", last_epoch, mono_ns());
        let mut bufs =
            vec![vec![0i32; n.min(port.frames_on_port() as usize)]; port.geometry().channels as usize];
        let mut nfr = 1u64;
        while !stop.load(Ordering::Relaxed) {
            match port.wait(nfr + n as u64 - 1, Duration::from_millis(500)) {
                Ok(_) | Err(Error::Timeout { .. }) => {}
                Err(Error::Device { code, message }) => {
                    errors += 1;
                    println!("DEVICE code={code} at_ns={} message={}", mono_ns(), message.replace(' ', "_"));
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
    println!("RESULT delivered={delivered} lost={lost} corrupted={corrupted} epochs={epochs} device_errors={errors}");
}
