//! Part 3: wake latency, from a publish to a blocked reader process running.
//!
//! - raw futex: two processes and a shared word; the parent stamps CLOCK_MONOTONIC, bumps
//!   the word and FUTEX_WAKEs; the child, blocked in FUTEX_WAIT, takes the time when it runs
//!   and answers the same way (ping-pong), so the parent knows it is blocked again.
//! - bass: the parent publishes a chunk stamped with CLOCK_MONOTONIC (the chunk table's
//!   `mono_ns`) just before `Writer::publish`; 1, 8 or 64 reader processes blocked in
//!   `Port::wait` take the time when `wait` returns, then read the chunk.
//! - bass on a sealed memfd port (`bassd --port-backing memfd`): the same 1-reader case, the
//!   reader holding an inherited read-only descriptor of the memfd, so its calls skip the
//!   file port's SIGBUS guard (neither makes a system call per call); interleaved with the raw
//!   futex and the file reader.
//! - the seed's BASC client: `GetBlocks` runs every 250 ms and calls getAudioData; the
//!   latency of a chunk is from its publication to the poll that obtains it.
//!
//! All publishes are spaced by a random 3–6 ms so that every waiter is really asleep.

use std::collections::BTreeMap;
use std::sync::atomic::Ordering::{Acquire, Relaxed, Release};
use std::time::{Duration, Instant};

use bassclient::sys::{futex_wait, futex_wake_all, monotonic_ns};
use bassclient::{ChunkMeta, Error, Geometry, Port, PortParams, Source, State, Writer};

use crate::procs::{finish_all, spawn_ready, Child};
use crate::shm::Region;
use crate::stats::{fmt_ns, fmt_ratio, median, quantile, spread};

/// Reader process counts.
pub const READERS: &[usize] = &[1, 8, 64];

/// A latency distribution (ns), pooled over repetitions, with per-repetition medians.
#[derive(Clone, Debug, Default)]
pub struct Dist {
    /// All samples.
    pub all: Vec<f64>,
    /// Median of each repetition.
    pub rep_medians: Vec<f64>,
}

impl Dist {
    fn add_rep(&mut self, v: Vec<f64>) {
        self.rep_medians.push(median(&v));
        self.all.extend(v);
    }

    /// Median of all samples.
    pub fn median(&self) -> f64 {
        median(&self.all)
    }

    /// 99th percentile.
    pub fn p99(&self) -> f64 {
        quantile(&self.all, 0.99)
    }

    /// Largest sample.
    pub fn max(&self) -> f64 {
        self.all.iter().cloned().fold(f64::NAN, f64::max)
    }
}

/// Results of part 3.
#[derive(Clone, Debug, Default)]
pub struct WakeResults {
    /// Raw futex, one waiter (ping direction).
    pub raw: Dist,
    /// bass, per reader count: every reader's wake latency.
    pub bass: BTreeMap<usize, Dist>,
    /// bass, per reader count: per publish, the latency of the last reader to run.
    pub bass_last: BTreeMap<usize, Dist>,
    /// bass, per reader count: wake + `get_audio_data` of the chunk (data in hand).
    pub bass_data: BTreeMap<usize, Dist>,
    /// Per repetition: bass (1 reader) median / raw futex median.
    pub ratio_1: Vec<f64>,
    /// bass, 1 reader of a sealed memfd port, interleaved with `raw`.
    pub bass_memfd: Dist,
    /// Per repetition: bass memfd (1 reader) median / raw futex median.
    pub ratio_memfd: Vec<f64>,
    /// Raw futex, per waiter count (> 1): every waiter's wake latency; the waiters copy the
    /// block out after waking, as the bass readers do.
    pub raw_n: BTreeMap<usize, Dist>,
    /// Raw futex, per waiter count: per wake, the latency of the last waiter to run.
    pub raw_n_last: BTreeMap<usize, Dist>,
    /// Per waiter count, per repetition: bass median / raw futex median (each reader).
    pub ratio_n: BTreeMap<usize, Vec<f64>>,
    /// Per waiter count, per repetition: the same for the last reader of each publish.
    pub ratio_n_last: BTreeMap<usize, Vec<f64>>,
    /// bass on a sealed memfd port, per reader count (> 1): every reader's wake latency.
    pub bass_memfd_n: BTreeMap<usize, Dist>,
    /// The same, per publish, the latency of the last reader to run.
    pub bass_memfd_n_last: BTreeMap<usize, Dist>,
    /// Per reader count, per repetition: bass memfd median / raw futex median (each reader).
    pub ratio_n_memfd: BTreeMap<usize, Vec<f64>>,
    /// The same for the last reader of each publish.
    pub ratio_n_memfd_last: BTreeMap<usize, Vec<f64>>,
    /// Diagnostic: bass writer, a reader doing a bare FUTEX_WAIT on the port's futex word
    /// instead of `Port::wait` (separates writer-side from reader-side overhead).
    pub bass_raw_waiter: Dist,
    /// Per reader count, per repetition: a reader's CPU time per chunk (wake, read, wait).
    pub reader_cpu: BTreeMap<usize, Vec<f64>>,
    /// Per reader count (> 1), per repetition: a memfd-port reader's CPU time per chunk.
    pub reader_cpu_memfd: BTreeMap<usize, Vec<f64>>,
    /// Per waiter count (> 1), per repetition: a raw futex waiter's CPU time per wake
    /// (copying the block).
    pub raw_waiter_cpu: BTreeMap<usize, Vec<f64>>,
    /// Per repetition: CPU per chunk of the bare-futex reader.
    pub bare_reader_cpu: Vec<f64>,
    /// The 250 ms polling client.
    pub poll: Dist,
    /// Publishes per configuration and repetition.
    pub publishes: usize,
}

/// A random spacing between wake-ups, 3 to 6 ms (fastrand's thread-local generator).
fn random_gap() -> Duration {
    Duration::from_micros(fastrand::u64(3000..6000))
}

const PING: usize = 0;
const PING_T: usize = 8;
const PONG: usize = 16;
const STOP: usize = 20;

/// The parent side of the raw futex ping-pong.
struct Pinger {
    region: Region,
    kid: Child,
    path: std::path::PathBuf,
}

impl Pinger {
    fn start() -> Pinger {
        let path = bassclient::paths::runtime_dir().join("bench-futex");
        let region = Region::create(&path, 4096);
        let mut kid = Child::spawn("futex-pong", &[path.display().to_string()]);
        kid.ready();
        Pinger { region, kid, path }
    }

    /// One ping; returns when the child has answered (and is about to block again).
    fn ping(&self) {
        let r = &self.region;
        let pong = r.u32_at(PONG).load(Acquire);
        r.u64_at(PING_T).store(monotonic_ns(), Relaxed);
        r.u32_at(PING).fetch_add(1, Release);
        futex_wake_all(r.u32_at(PING));
        while r.u32_at(PONG).load(Acquire) == pong {
            futex_wait(r.u32_at(PONG), pong, Duration::from_secs(1));
        }
    }

    /// Stops the child; returns its latencies (ns).
    fn finish(self) -> Vec<f64> {
        let r = &self.region;
        r.u32_at(STOP).store(1, Release);
        r.u32_at(PING).fetch_add(1, Release);
        futex_wake_all(r.u32_at(PING));
        let lines = self.kid.finish();
        let _ = std::fs::remove_file(&self.path);
        lines.iter().filter_map(|l| l.strip_prefix("lat ")).filter_map(|v| v.parse().ok()).collect()
    }
}

/// Child: the other side of the raw futex ping-pong.
pub fn child_futex_pong(args: &[String]) {
    let r = Region::open(std::path::Path::new(&args[0]), 4096);
    let mut lats = Vec::new();
    let mut seq = r.u32_at(PING).load(Acquire);
    crate::procs::say_ready();
    loop {
        while r.u32_at(PING).load(Acquire) == seq {
            futex_wait(r.u32_at(PING), seq, Duration::MAX);
        }
        let t = monotonic_ns();
        seq = r.u32_at(PING).load(Acquire);
        if r.u32_at(STOP).load(Acquire) != 0 {
            break;
        }
        lats.push(t.saturating_sub(r.u64_at(PING_T).load(Relaxed)));
        r.u32_at(PONG).fetch_add(1, Release);
        futex_wake_all(r.u32_at(PONG));
    }
    let out: String = lats.iter().map(|l| format!("lat {l}\n")).collect();
    print!("{out}");
}

/// Slots of the raw baseline's sample rings (as many as the wake port's chunks).
const RAW_SLOTS: usize = 64;
/// Bytes of one channel's ring in the raw baseline's region.
const RAW_RING_BYTES: usize = RAW_SLOTS * WAKE_NFPC as usize * 4;
/// The raw baseline's region: a page of control words, then one ring per channel (2).
const RAW_REGION_BYTES: usize = 4096 + 2 * RAW_RING_BYTES;

/// Byte offset of channel `c`'s block for wake number `seq` in the raw baseline's region.
fn raw_block(c: usize, seq: u32) -> usize {
    4096 + c * RAW_RING_BYTES + (seq as usize % RAW_SLOTS) * WAKE_NFPC as usize * 4
}

/// Raw-futex baseline for many waiters: `readers` processes blocked in FUTEX_WAIT on one
/// shared word; per wake the parent stamps CLOCK_MONOTONIC, bumps the word and issues one
/// FUTEX_WAKE of all of them, exactly the system calls a bass publish makes, without bass.
///
/// Like a bass publish, the parent first writes a block of the wake port's size (64 frames
/// × 2 channels, one ring per channel, as in a port), and like a bass reader every waiter
/// copies it out (plain `memcpy`s) and takes the time again when it has the data: so the
/// bass readers, which read their chunk and stamp both times, are compared like with like.
/// The ring has [`RAW_SLOTS`] slots, so the parent never writes a block a waiter may still
/// be copying.
struct RawBroadcast {
    path: std::path::PathBuf,
    region: Region,
    kids: Vec<Child>,
    block: Vec<i32>,
}

impl RawBroadcast {
    fn start(readers: usize) -> RawBroadcast {
        let path = bassclient::paths::runtime_dir().join("bench-futex-n");
        let region = Region::create(&path, RAW_REGION_BYTES);
        let kids = spawn_ready(readers, "futex-waiter", &[path.display().to_string()]);
        RawBroadcast { path, region, kids, block: vec![7; WAKE_NFPC as usize] }
    }

    /// Writes the next block, then wakes every waiter, stamped with the current time.
    fn wake(&self) {
        let next = self.region.u32_at(PING).load(Relaxed).wrapping_add(1);
        for c in 0..2 {
            // SAFETY: `raw_block` is inside the region (RAW_REGION_BYTES) and holds WAKE_NFPC
            // samples; no waiter reads this slot now (it was last published RAW_SLOTS wakes
            // ago, and every waiter copies its block right after waking).
            unsafe {
                std::ptr::copy_nonoverlapping(
                    self.block.as_ptr(),
                    self.region.ptr().add(raw_block(c, next)) as *mut i32,
                    self.block.len(),
                )
            };
        }
        self.region.u64_at(PING_T).store(monotonic_ns(), Relaxed);
        self.region.u32_at(PING).fetch_add(1, Release);
        futex_wake_all(self.region.u32_at(PING));
    }

    /// Stops the waiters; returns their latencies and their median CPU time per wake.
    fn finish(self) -> Samples {
        self.region.u32_at(STOP).store(1, Release);
        self.region.u32_at(PING).fetch_add(1, Release);
        futex_wake_all(self.region.u32_at(PING));
        let lines = finish_all(self.kids);
        let _ = std::fs::remove_file(&self.path);
        samples_of(&lines)
    }
}

/// Child: one waiter of the raw-futex broadcast baseline; prints `seq latency_ns data_ns`
/// per wake (woken; block copied out).
pub fn child_futex_waiter(args: &[String]) {
    let r = Region::open(std::path::Path::new(&args[0]), RAW_REGION_BYTES);
    let mut seq = r.u32_at(PING).load(Acquire);
    let (mut left, mut right) = (vec![0i32; WAKE_NFPC as usize], vec![0i32; WAKE_NFPC as usize]);
    let mut out = String::new();
    crate::procs::say_ready();
    let cpu0 = crate::procs::process_cpu_ns();
    loop {
        while r.u32_at(PING).load(Acquire) == seq {
            futex_wait(r.u32_at(PING), seq, Duration::MAX);
        }
        let t = monotonic_ns();
        seq = r.u32_at(PING).load(Acquire);
        if r.u32_at(STOP).load(Acquire) != 0 {
            break;
        }
        for (c, buf) in [&mut left, &mut right].into_iter().enumerate() {
            // SAFETY: the block is inside the region and holds WAKE_NFPC samples; the parent
            // wrote it before the Release increment of PING that this process loaded with
            // Acquire, and does not write that slot again for RAW_SLOTS wakes.
            unsafe {
                std::ptr::copy_nonoverlapping(
                    r.ptr().add(raw_block(c, seq)) as *const i32,
                    buf.as_mut_ptr(),
                    buf.len(),
                )
            };
            std::hint::black_box(&buf);
        }
        let data = monotonic_ns();
        let published = r.u64_at(PING_T).load(Relaxed);
        out.push_str(&format!("{seq} {} {}\n", t.saturating_sub(published), data.saturating_sub(published)));
    }
    out.push_str(&format!(
        "cpu_ns={} chunks={}\n",
        crate::procs::process_cpu_ns() - cpu0,
        out.lines().count()
    ));
    print!("{out}");
}

/// Frames per chunk of the wake-latency port (small: the copy is not what is measured).
const WAKE_NFPC: u32 = 64;

/// Latencies (ns) of one bass configuration.
struct Samples {
    /// Every reader's wake latency.
    each: Vec<f64>,
    /// Per publish, the latency of the last reader to run.
    last: Vec<f64>,
    /// Wake + `get_audio_data` (data in hand).
    data: Vec<f64>,
    /// The readers' median CPU per chunk (ns).
    cpu: f64,
}

/// The 1-reader interleaved comparison.
struct OneReader {
    raw: Vec<f64>,
    bass: Samples,
    bare: Samples,
    memfd: Samples,
}

/// A bass port with wake-latency readers attached.
struct WakePort {
    w: Writer,
    kids: Vec<Child>,
    data: Vec<i32>,
}

impl WakePort {
    fn start(name: &str, readers: usize, role: &str) -> WakePort {
        let geometry =
            Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: WAKE_NFPC, chunks_on_port: 64 };
        let params = PortParams { geometry, device: "bench:wake".into(), group: None };
        let mut w = Writer::create(name, &params).expect("create port");
        let data = vec![7i32; WAKE_NFPC as usize * 2];
        for _ in 0..64 {
            w.publish(Source::Interleaved(&data), ChunkMeta::default()).expect("publish");
        }
        let kids = spawn_ready(readers, role, &[name.to_owned()]);
        WakePort { w, kids, data }
    }

    /// Like [`WakePort::start`] with `readers` `wake-reader`s, but the port is a sealed memfd
    /// and each reader gets a read-only descriptor of it (inherited, as bassd would hand it
    /// over).
    fn start_memfd(name: &str, readers: usize) -> WakePort {
        let geometry =
            Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: WAKE_NFPC, chunks_on_port: 64 };
        let params = PortParams { geometry, device: "bench:wake-memfd".into(), group: None };
        let pending = Writer::prepare_memfd(name, &params, None).expect("create memfd port");
        let mut w = pending.commit().expect("commit memfd port");
        let data = vec![7i32; WAKE_NFPC as usize * 2];
        for _ in 0..64 {
            w.publish(Source::Interleaved(&data), ChunkMeta::default()).expect("publish");
        }
        let mut kids = Vec::new();
        for _ in 0..readers {
            let fd = w.reader_fd().expect("reader fd").expect("a memfd port");
            rustix::io::fcntl_setfd(&fd, rustix::io::FdFlags::empty()).expect("inheritable");
            let fd_arg = std::os::fd::AsRawFd::as_raw_fd(&fd).to_string();
            kids.push(Child::spawn("wake-reader", &[name.to_owned(), "fd".into(), fd_arg]));
        }
        for k in &mut kids {
            k.ready();
        }
        WakePort { w, kids, data }
    }

    /// Publishes one chunk stamped with the current time.
    fn publish(&mut self) {
        let meta = ChunkMeta { mono_ns: monotonic_ns(), ..ChunkMeta::default() };
        self.w.publish(Source::Interleaved(&self.data), meta).expect("publish");
    }

    /// Stops; returns the readers' latencies and their median CPU time per chunk.
    fn finish(self) -> Samples {
        self.w.stop();
        let lines = finish_all(self.kids);
        let _ = self.w.remove();
        samples_of(&lines)
    }
}

/// Parses the output of wake readers or raw waiters: `ID WAKE_NS DATA_NS` per wake (ID: the
/// publish it answers) and a `cpu_ns=… chunks=…` line per process.
fn samples_of(lines: &[String]) -> Samples {
    let (mut each, mut data_in_hand) = (Vec::new(), Vec::new());
    let mut last: BTreeMap<u64, f64> = BTreeMap::new();
    let cpu: Vec<f64> = lines
        .iter()
        .filter_map(|l| Some(crate::procs::field(l, "cpu_ns")? / crate::procs::field(l, "chunks")?.max(1.0)))
        .collect();
    for l in lines {
        let v: Vec<u64> = l.split_whitespace().filter_map(|x| x.parse().ok()).collect();
        if let [id, lat, dat] = v[..] {
            each.push(lat as f64);
            data_in_hand.push(dat as f64);
            let e = last.entry(id).or_insert(0.0);
            *e = e.max(lat as f64);
        }
    }
    Samples { each, last: last.into_values().collect(), data: data_in_hand, cpu: median(&cpu) }
}

/// `readers` readers of a file port, `readers` of a sealed memfd port and `readers` raw
/// futex waiters, all running at once; `n` wakes of each, interleaved wake by wake (random
/// 3–6 ms apart) so that the three see the same machine. Returns (file, memfd, raw).
fn many_side_by_side(readers: usize, n: usize) -> (Samples, Samples, Samples) {
    let mut file = WakePort::start("bench-wake-n", readers, "wake-reader");
    let mut memfd = WakePort::start_memfd("bench-wake-nm", readers);
    let raw = RawBroadcast::start(readers);
    std::thread::sleep(Duration::from_millis(50));
    for k in 0..3 * n {
        std::thread::sleep(random_gap());
        match k % 3 {
            0 => file.publish(),
            1 => memfd.publish(),
            _ => raw.wake(),
        }
    }
    (file.finish(), memfd.finish(), raw.finish())
}

/// The one-reader comparison, interleaved publish by publish so that all three see the
/// same machine: raw futex ping, bass publish to a `Port::wait` reader, bass publish to a
/// bare-futex reader.
fn one_reader_side_by_side(n: usize) -> OneReader {
    let pinger = Pinger::start();
    let mut a = WakePort::start("bench-wake-a", 1, "wake-reader");
    let mut b = WakePort::start("bench-wake-b", 1, "wake-raw-waiter");
    let mut m = WakePort::start_memfd("bench-wake-m", 1);
    // Experiment hook: a fourth reader from another build, interleaved with the rest.
    let mut alt = std::env::var_os("BASS_BENCH_ALT_EXE").map(|exe| {
        let mut p = WakePort::start("bench-wake-c", 0, "wake-reader");
        let mut k = Child::spawn_exe(std::path::Path::new(&exe), "wake-reader", &["bench-wake-c".into()]);
        k.ready();
        p.kids.push(k);
        p
    });
    let ways = if alt.is_some() { 5 } else { 4 };
    std::thread::sleep(Duration::from_millis(50));
    for k in 0..ways * n {
        std::thread::sleep(random_gap());
        match k % ways {
            0 => pinger.ping(),
            1 => a.publish(),
            2 => b.publish(),
            3 => m.publish(),
            _ => alt.as_mut().expect("alt").publish(),
        }
    }
    if let Some(p) = alt {
        let v = p.finish();
        println!(
            "  alternative build's reader: median {} p99 {} CPU/chunk {}",
            fmt_ns(median(&v.each)),
            fmt_ns(quantile(&v.each, 0.99)),
            fmt_ns(v.cpu)
        );
    }
    OneReader { raw: pinger.finish(), bass: a.finish(), bare: b.finish(), memfd: m.finish() }
}

/// Child: a reader blocked in `Port::wait`; prints `lfi wake_ns data_ns` per chunk.
pub fn child_wake_reader(args: &[String]) {
    let port = match (args.get(1).map(String::as_str), args.get(2)) {
        (Some("fd"), Some(fd)) => {
            let fd: i32 = fd.parse().expect("fd number");
            // SAFETY: the parent left this descriptor open across exec for this process
            // alone (`WakePort::start_memfd`); nothing else here owns or closes it.
            let fd = unsafe { <std::os::fd::OwnedFd as std::os::fd::FromRawFd>::from_raw_fd(fd) };
            Port::from_fd(fd, &args[0]).expect("port from fd")
        }
        _ => Port::open(&args[0]).expect("open port"),
    };
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let cap = port.geometry().frames_per_chunk as usize * 8;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut out = String::new();
    crate::procs::say_ready();
    let cpu0 = crate::procs::process_cpu_ns();
    loop {
        match port.wait(nfr, Duration::from_secs(30)) {
            Ok(lfi) => {
                let woke = monotonic_ns();
                let mut bufs = [&mut l[..], &mut r[..]];
                port.get_audio_data(cap, &mut nfr, &mut bufs).expect("read");
                let read = monotonic_ns();
                let published = port.chunk_info(lfi).map(|c| c.mono_ns).unwrap_or(0);
                if published > 0 {
                    out.push_str(&format!(
                        "{lfi} {} {}\n",
                        woke.saturating_sub(published),
                        read.saturating_sub(published)
                    ));
                }
            }
            Err(Error::Stopped { .. }) => break,
            Err(e) => panic!("wake reader: {e}"),
        }
    }
    out.push_str(&format!(
        "cpu_ns={} chunks={}\n",
        crate::procs::process_cpu_ns() - cpu0,
        out.lines().count()
    ));
    print!("{out}");
}

/// Child: like `wake-reader`, but blocks with a bare FUTEX_WAIT on the port header's futex
/// word (read-only mapping) instead of `Port::wait`.
pub fn child_raw_waiter(args: &[String]) {
    use bassclient::format::Header;
    use std::mem::offset_of;
    let port = Port::open(&args[0]).expect("open port");
    let map = Region::open_ro(port.path(), 4096);
    let futex = map.u32_at(offset_of!(Header, futex));
    let lfi_word = map.u64_at(offset_of!(Header, last_frame_index));
    let state = map.u32_at(offset_of!(Header, state));
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let cap = port.geometry().frames_per_chunk as usize * 8;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut out = String::new();
    // Experiment knobs (not used by the harness itself).
    let timeout = match std::env::var("BENCH_WAITER_TIMEOUT_MS").ok().and_then(|v| v.parse().ok()) {
        Some(ms) if ms > 0 => Duration::from_millis(ms),
        _ => Duration::MAX,
    };
    let do_fstat = std::env::var("BENCH_WAITER_FSTAT").is_ok();
    crate::procs::say_ready();
    let cpu0 = crate::procs::process_cpu_ns();
    loop {
        if do_fstat {
            let _ = std::fs::metadata(port.path());
        }
        let seq = futex.load(Acquire);
        let lfi = lfi_word.load(Acquire);
        if lfi < nfr {
            if state.load(Acquire) == State::Stopped as u32 {
                break;
            }
            futex_wait(futex, seq, timeout);
            continue;
        }
        let woke = monotonic_ns();
        let mut bufs = [&mut l[..], &mut r[..]];
        port.get_audio_data(cap, &mut nfr, &mut bufs).expect("read");
        let read = monotonic_ns();
        let published = port.chunk_info(lfi).map(|c| c.mono_ns).unwrap_or(0);
        if published > 0 {
            out.push_str(&format!(
                "{lfi} {} {}\n",
                woke.saturating_sub(published),
                read.saturating_sub(published)
            ));
        }
    }
    out.push_str(&format!(
        "cpu_ns={} chunks={}\n",
        crate::procs::process_cpu_ns() - cpu0,
        out.lines().count()
    ));
    print!("{out}");
}

fn polling(readers: usize, duration: Duration) -> Vec<f64> {
    let name = "bench-poll";
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: 2205, chunks_on_port: 20 };
    let params = PortParams { geometry, device: "bench:poll".into(), group: None };
    let mut w = Writer::create(name, &params).expect("create port");
    let data = vec![7i32; 2205 * 2];
    let kids = spawn_ready(readers, "poll-reader", &[name.to_owned()]);
    let start = Instant::now();
    let mut next = start;
    while start.elapsed() < duration {
        next += Duration::from_millis(50);
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        let meta = ChunkMeta { mono_ns: monotonic_ns(), ..ChunkMeta::default() };
        w.publish(Source::Interleaved(&data), meta).expect("publish");
    }
    w.stop();
    let lines = finish_all(kids);
    let _ = w.remove();
    lines.iter().filter_map(|l| l.strip_prefix("lat ")).filter_map(|v| v.parse().ok()).collect()
}

/// Child: the seed's BASC `GetBlocks` loop, a periodic 250 ms task calling getAudioData.
/// Prints `lat NS` for every chunk obtained (from the chunk's publication to the poll).
pub fn child_poll_reader(args: &[String]) {
    let port = Port::open(&args[0]).expect("open port");
    let nfpc = u64::from(port.geometry().frames_per_chunk);
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let cap = 44100;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut out = String::new();
    crate::procs::say_ready();
    // Random phase, as a client started at any moment.
    std::thread::sleep(Duration::from_micros(monotonic_ns() % 250_000));
    let mut next = Instant::now();
    loop {
        next += Duration::from_millis(250);
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        let first = nfr;
        let mut bufs = [&mut l[..], &mut r[..]];
        let got = port.get_audio_data(cap, &mut nfr, &mut bufs).expect("read");
        let t = monotonic_ns();
        // The first chunk that starts at or after `first` (chunks start at k * nFPC + 1).
        let mut f = (first - 1).div_ceil(nfpc) * nfpc + 1;
        while got.frames > 0 && f + nfpc - 1 < nfr {
            if let Ok(ci) = port.chunk_info(f) {
                out.push_str(&format!("lat {}\n", t.saturating_sub(ci.mono_ns)));
            }
            f += nfpc;
        }
        if port
            .info()
            .map(|i| !matches!(i.state, Some(State::Capturing | State::Idle | State::Starting)))
            .unwrap_or(true)
        {
            break;
        }
    }
    print!("{out}");
}

/// Runs part 3.
pub fn run(reps: usize, quick: bool) -> WakeResults {
    let n = if quick { 80 } else { 250 };
    let mut res = WakeResults { publishes: n, ..WakeResults::default() };
    for rep in 0..reps {
        let OneReader { raw, bass, bare, memfd } = one_reader_side_by_side(n);
        let mfd = memfd.each;
        println!(
            "  rep {} bass 1 reader, sealed memfd port: median {} p99 {} (CPU/chunk {}) | memfd / raw {}",
            rep + 1,
            fmt_ns(median(&mfd)),
            fmt_ns(quantile(&mfd, 0.99)),
            fmt_ns(memfd.cpu),
            fmt_ratio(median(&mfd) / median(&raw))
        );
        res.ratio_memfd.push(median(&mfd) / median(&raw));
        res.bass_memfd.add_rep(mfd);
        let (one, data, cpu_one) = (bass.each, bass.data, bass.cpu);
        let (cpu_bare, bare) = (bare.cpu, bare.each);
        res.reader_cpu.entry(1).or_default().push(cpu_one);
        res.bare_reader_cpu.push(cpu_bare);
        let (raw_med, one_med) = (median(&raw), median(&one));
        println!(
            "  rep {} raw futex: median {} p99 {} | bass 1 reader: median {} p99 {} (data in hand {}, CPU/chunk {}) | bass writer + bare FUTEX_WAIT reader: median {} (CPU/chunk {}) | ratio {}",
            rep + 1,
            fmt_ns(raw_med),
            fmt_ns(quantile(&raw, 0.99)),
            fmt_ns(one_med),
            fmt_ns(quantile(&one, 0.99)),
            fmt_ns(median(&data)),
            fmt_ns(cpu_one),
            fmt_ns(median(&bare)),
            fmt_ns(cpu_bare),
            fmt_ratio(one_med / raw_med)
        );
        res.ratio_1.push(one_med / raw_med);
        res.raw.add_rep(raw);
        res.bass_raw_waiter.add_rep(bare);
        res.bass.entry(1).or_default().add_rep(one.clone());
        res.bass_last.entry(1).or_default().add_rep(one);
        res.bass_data.entry(1).or_default().add_rep(data);
        for &k in READERS.iter().filter(|&&k| k > 1) {
            let (bass_k, m, raw_k) = many_side_by_side(k, n);
            let Samples { each, last, data, cpu } = bass_k;
            res.reader_cpu.entry(k).or_default().push(cpu);
            println!(
                "  rep {} bass {k:>2} readers: median {} p99 {} max {}; last reader median {}; data in hand median {}; reader CPU/chunk {}",
                rep + 1,
                fmt_ns(median(&each)),
                fmt_ns(quantile(&each, 0.99)),
                fmt_ns(each.iter().cloned().fold(0.0, f64::max)),
                fmt_ns(median(&last)),
                fmt_ns(median(&data)),
                fmt_ns(cpu)
            );
            println!(
                "  rep {} raw futex, {k:>2} waiters copying the block: median {} p99 {}; last waiter median {}; waiter CPU/wake {} | bass / raw: each {}, last {}",
                rep + 1,
                fmt_ns(median(&raw_k.each)),
                fmt_ns(quantile(&raw_k.each, 0.99)),
                fmt_ns(median(&raw_k.last)),
                fmt_ns(raw_k.cpu),
                fmt_ratio(median(&each) / median(&raw_k.each)),
                fmt_ratio(median(&last) / median(&raw_k.last))
            );
            res.ratio_n.entry(k).or_default().push(median(&each) / median(&raw_k.each));
            res.ratio_n_last.entry(k).or_default().push(median(&last) / median(&raw_k.last));
            println!(
                "  rep {} bass {k:>2} readers, sealed memfd port: median {}; last reader median {}; reader CPU/chunk {} | memfd / raw: each {}, last {}",
                rep + 1,
                fmt_ns(median(&m.each)),
                fmt_ns(median(&m.last)),
                fmt_ns(m.cpu),
                fmt_ratio(median(&m.each) / median(&raw_k.each)),
                fmt_ratio(median(&m.last) / median(&raw_k.last))
            );
            res.reader_cpu_memfd.entry(k).or_default().push(m.cpu);
            res.raw_waiter_cpu.entry(k).or_default().push(raw_k.cpu);
            res.ratio_n_memfd.entry(k).or_default().push(median(&m.each) / median(&raw_k.each));
            res.ratio_n_memfd_last.entry(k).or_default().push(median(&m.last) / median(&raw_k.last));
            res.bass_memfd_n.entry(k).or_default().add_rep(m.each);
            res.bass_memfd_n_last.entry(k).or_default().add_rep(m.last);
            res.raw_n.entry(k).or_default().add_rep(raw_k.each);
            res.raw_n_last.entry(k).or_default().add_rep(raw_k.last);
            res.bass.entry(k).or_default().add_rep(each);
            res.bass_last.entry(k).or_default().add_rep(last);
            res.bass_data.entry(k).or_default().add_rep(data);
        }
    }
    let poll = polling(4, Duration::from_secs(if quick { 2 } else { 6 }));
    println!(
        "  250 ms polling client: median {} p99 {}",
        fmt_ns(median(&poll)),
        fmt_ns(quantile(&poll, 0.99))
    );
    res.poll.add_rep(poll);
    println!("  bass (1 reader) / raw futex, median per repetition: {}", spread(&res.ratio_1, fmt_ratio));
    println!(
        "  bass (1 reader, sealed memfd) / raw futex, median per repetition: {}",
        spread(&res.ratio_memfd, fmt_ratio)
    );
    res
}
