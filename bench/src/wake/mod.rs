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
//! - bass callback stream (`bassport::stream::Stream`, one chunk per block): the time from
//!   the chunk's stamp to the block callback being entered; interleaved with the raw futex
//!   and the `Port::wait` readers at 1, 8 and 64 readers.
//!
//! All publishes are spaced by a random 3–6 ms so that every waiter is really asleep.

use std::collections::BTreeMap;
use std::time::Duration;

use bassport::sys::monotonic_ns;
use bassport::{ChunkMeta, Geometry, PortParams, Source, Writer};

use crate::procs::{finish_all, spawn_ready, Child};
use crate::stats::{fmt_ns, fmt_ratio, median, quantile, spread};

#[allow(unsafe_code)] // the raw futex and copy the wake is compared with
mod raw;
#[allow(unsafe_code)] // a port descriptor inherited from the parent
mod readers;

pub use raw::{child_futex_pong, child_futex_waiter, child_raw_waiter};
use raw::{Pinger, RawBroadcast};
use readers::polling;
pub use readers::{child_poll_reader, child_stream_reader, child_wake_reader};
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
    /// Callback stream, per reader count: every reader's publish → callback-entered latency.
    pub stream: BTreeMap<usize, Dist>,
    /// Per reader count, per repetition: callback median / blocking (`Port::wait`) median.
    pub ratio_stream_blocking: BTreeMap<usize, Vec<f64>>,
    /// Per reader count, per repetition: callback median / raw futex median.
    pub ratio_stream_raw: BTreeMap<usize, Vec<f64>>,
    /// The same with p99s, per reader count and repetition: callback / blocking.
    pub ratio_stream_blocking_p99: BTreeMap<usize, Vec<f64>>,
    /// The same with p99s: callback / raw futex.
    pub ratio_stream_raw_p99: BTreeMap<usize, Vec<f64>>,
    /// Publishes per configuration and repetition.
    pub publishes: usize,
}

/// A random spacing between wake-ups, 3 to 6 ms (fastrand's thread-local generator).
fn random_gap() -> Duration {
    Duration::from_micros(fastrand::u64(3000..6000))
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
    stream: Samples,
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

/// `readers` readers of a file port, `readers` of a sealed memfd port, `readers` callback
/// streams of a file port and `readers` raw futex waiters, all running at once; `n` wakes of
/// each, interleaved wake by wake (random 3–6 ms apart) so that the four see the same
/// machine. Returns (file, memfd, stream, raw).
fn many_side_by_side(readers: usize, n: usize) -> (Samples, Samples, Samples, Samples) {
    let mut file = WakePort::start("bench-wake-n", readers, "wake-reader");
    let mut memfd = WakePort::start_memfd("bench-wake-nm", readers);
    let mut stream = WakePort::start("bench-wake-ns", readers, "stream-reader");
    let raw = RawBroadcast::start(readers);
    std::thread::sleep(Duration::from_millis(50));
    for k in 0..4 * n {
        std::thread::sleep(random_gap());
        match k % 4 {
            0 => file.publish(),
            1 => memfd.publish(),
            2 => stream.publish(),
            _ => raw.wake(),
        }
    }
    (file.finish(), memfd.finish(), stream.finish(), raw.finish())
}

/// The one-reader comparison, interleaved publish by publish so that all three see the
/// same machine: raw futex ping, bass publish to a `Port::wait` reader, bass publish to a
/// bare-futex reader.
fn one_reader_side_by_side(n: usize) -> OneReader {
    let pinger = Pinger::start();
    let mut a = WakePort::start("bench-wake-a", 1, "wake-reader");
    let mut b = WakePort::start("bench-wake-b", 1, "wake-raw-waiter");
    let mut m = WakePort::start_memfd("bench-wake-m", 1);
    let mut s = WakePort::start("bench-wake-s", 1, "stream-reader");
    // Experiment hook: a fourth reader from another build, interleaved with the rest.
    let mut alt = std::env::var_os("BASS_BENCH_ALT_EXE").map(|exe| {
        let mut p = WakePort::start("bench-wake-c", 0, "wake-reader");
        let mut k = Child::spawn_exe(std::path::Path::new(&exe), "wake-reader", &["bench-wake-c".into()]);
        k.ready();
        p.kids.push(k);
        p
    });
    let ways = if alt.is_some() { 6 } else { 5 };
    std::thread::sleep(Duration::from_millis(50));
    for k in 0..ways * n {
        std::thread::sleep(random_gap());
        match k % ways {
            0 => pinger.ping(),
            1 => a.publish(),
            2 => b.publish(),
            3 => m.publish(),
            4 => s.publish(),
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
    OneReader {
        raw: pinger.finish(),
        bass: a.finish(),
        bare: b.finish(),
        memfd: m.finish(),
        stream: s.finish(),
    }
}

impl WakeResults {
    /// Records one repetition of the callback stream with `readers` readers against the
    /// blocking readers and the raw futex of the same interleaved run, and prints it.
    /// `blocking`: the `Port::wait` readers' (wake, data in hand) latencies; the callback is
    /// entered after its block is copied, so the second is its like-for-like (printed only).
    fn add_stream(
        &mut self,
        rep: usize,
        readers: usize,
        s: Samples,
        blocking: (&[f64], &[f64]),
        raw: &[f64],
    ) {
        let (blocking, data) = blocking;
        let cb = s.each;
        let (c50, c99) = (median(&cb), quantile(&cb, 0.99));
        let (b50, b99) = (median(blocking), quantile(blocking, 0.99));
        let (r50, r99) = (median(raw), quantile(raw, 0.99));
        println!(
            "  rep {} callback stream, {readers:>2} reader{}: p50 {} p99 {} | blocking p50 {} p99 {} | raw futex p50 {} p99 {} | callback / blocking {} (p99 {}), callback / raw {} (p99 {}); callback / blocking data in hand {}; CPU/chunk {}",
            rep + 1,
            if readers == 1 { "" } else { "s" },
            fmt_ns(c50),
            fmt_ns(c99),
            fmt_ns(b50),
            fmt_ns(b99),
            fmt_ns(r50),
            fmt_ns(r99),
            fmt_ratio(c50 / b50),
            fmt_ratio(c99 / b99),
            fmt_ratio(c50 / r50),
            fmt_ratio(c99 / r99),
            fmt_ratio(c50 / median(data)),
            fmt_ns(s.cpu)
        );
        self.ratio_stream_blocking.entry(readers).or_default().push(c50 / b50);
        self.ratio_stream_raw.entry(readers).or_default().push(c50 / r50);
        self.ratio_stream_blocking_p99.entry(readers).or_default().push(c99 / b99);
        self.ratio_stream_raw_p99.entry(readers).or_default().push(c99 / r99);
        self.stream.entry(readers).or_default().add_rep(cb);
    }
}

/// Runs part 3.
pub fn run(reps: usize, quick: bool) -> WakeResults {
    let n = if quick { 80 } else { 250 };
    let mut res = WakeResults { publishes: n, ..WakeResults::default() };
    for rep in 0..reps {
        one_reader_rep(&mut res, rep, n);
        for &k in READERS.iter().filter(|&&k| k > 1) {
            many_readers_rep(&mut res, rep, k, n);
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

/// Repetition `rep` with one reader, `n` publishes: the raw futex, bass on a file and a sealed
/// memfd port, a bare FUTEX_WAIT reader and a callback stream, side by side; added to `res`
/// and printed.
fn one_reader_rep(res: &mut WakeResults, rep: usize, n: usize) {
    let OneReader { raw, bass, bare, memfd, stream } = one_reader_side_by_side(n);
    res.add_stream(rep, 1, stream, (&bass.each, &bass.data), &raw);
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
}

/// Repetition `rep` with `k` readers, `n` publishes: bass on a file and a sealed memfd port, a
/// callback stream and a raw futex waking `k` waiters, side by side; added to `res` and
/// printed.
fn many_readers_rep(res: &mut WakeResults, rep: usize, k: usize, n: usize) {
    let (bass_k, m, stream_k, raw_k) = many_side_by_side(k, n);
    res.add_stream(rep, k, stream_k, (&bass_k.each, &bass_k.data), &raw_k.each);
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
