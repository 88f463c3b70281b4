//! Part 2: cost of publishing one chunk, against window size and attached readers, for
//! the ring and for the model of the original design (see `original.rs`).
//!
//! 44.1 kHz stereo, chunks of 2205 frames (the seed's Acquire defaults). Windows of
//! 0.1, 1, 10 and 60 s; 0, 1, 8 and 64 reader processes blocked in a wait and reading
//! every chunk. The window is filled (every page touched) before timing; then chunks are
//! published every few milliseconds and each publish call is timed in the writer.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, Writer};

use crate::original::{self, OrigPort};
use crate::procs::{field, finish_all, spawn_ready};
use crate::stats::{fmt_ns, fmt_ratio, median, quantile, spread};

/// Frames per chunk (the seed's default).
pub const NFPC: u32 = 2205;
/// Windows measured: (seconds, chunks on port).
pub const WINDOWS: &[(f64, u32)] = &[(0.1, 2), (1.0, 20), (10.0, 200), (60.0, 1200)];
/// Reader process counts.
pub const READERS: &[usize] = &[0, 1, 8, 64];

/// Chunk sizes of the 10 s-window sweep.
pub const SWEEP_CHUNKS: &[u32] = &[64, 256, 2205];

/// One chunk size of the sweep (10 s window, 1 reader).
#[derive(Clone, Debug)]
pub struct SweepRow {
    /// nFPC.
    pub frames_per_chunk: u32,
    /// Per repetition: ring CPU per publish (ns).
    pub ring_ns: Vec<f64>,
    /// Per repetition: original CPU per publish (ns).
    pub orig_ns: Vec<f64>,
}

/// Which design.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Design {
    /// bass's ring.
    Ring,
    /// The original shifting array with whole-port reads.
    Original,
}

/// One configuration's results over the repetitions.
#[derive(Clone, Debug)]
pub struct PubCell {
    /// Design.
    pub design: Design,
    /// Window in seconds.
    pub window_s: f64,
    /// Readers attached.
    pub readers: usize,
    /// Per repetition: median CPU time of the writer thread per publish (ns).
    pub publish_ns: Vec<f64>,
    /// Per repetition: median wall time of a publish call (ns), preemption included.
    pub wall_ns: Vec<f64>,
    /// Per repetition: 90th percentile publish time (ns).
    pub publish_p90_ns: Vec<f64>,
    /// Per repetition: median time of one reader's read of a chunk (ns), over readers.
    pub read_ns: Vec<f64>,
    /// Chunks published (timed) per repetition.
    pub chunks: Vec<usize>,
}

/// Results of part 2.
#[derive(Clone, Debug, Default)]
pub struct PublishResults {
    /// All cells.
    pub cells: Vec<PubCell>,
    /// Time between publishes (ms).
    pub period_ms: f64,
    /// Where the time of one publish goes.
    pub breakdown: Breakdown,
    /// Chunk-size sweep at a 10 s window.
    pub sweep: Vec<SweepRow>,
}

impl PublishResults {
    /// The cell of a configuration.
    pub fn cell(&self, design: Design, window_s: f64, readers: usize) -> Option<&PubCell> {
        self.cells.iter().find(|c| c.design == design && c.window_s == window_s && c.readers == readers)
    }

    /// Median publish time of a configuration.
    pub fn publish_median(&self, design: Design, window_s: f64, readers: usize) -> f64 {
        self.cell(design, window_s, readers).map(|c| median(&c.publish_ns)).unwrap_or(f64::NAN)
    }
}

fn chunk_of(nfpc: u32) -> Vec<i32> {
    (0..nfpc as i32 * 2).map(|i| i.wrapping_mul(104729)).collect()
}

fn chunk() -> Vec<i32> {
    chunk_of(NFPC)
}

struct Pace {
    period: Duration,
    max_chunks: usize,
    min_chunks: usize,
    budget: Duration,
}

/// CPU time of the calling thread (ns).
pub fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid out-pointer; CLOCK_THREAD_CPUTIME_ID always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Times each publish: (CPU time of the writer thread, wall time), in ns.
fn time_publishes(pace: &Pace, mut publish: impl FnMut()) -> (Vec<f64>, Vec<f64>) {
    let start = Instant::now();
    let mut times = Vec::with_capacity(pace.max_chunks);
    let mut walls = Vec::with_capacity(pace.max_chunks);
    let mut clock = Vec::with_capacity(pace.max_chunks);
    let mut next = Instant::now();
    while times.len() < pace.max_chunks && (times.len() < pace.min_chunks || start.elapsed() < pace.budget) {
        next += pace.period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
        // Three clock reads: the first absorbs the cold first syscall after the sleep, the
        // warm pair (c1, c2) measures the clock's own cost, subtracted below.
        let _ = thread_cpu_ns();
        let c1 = thread_cpu_ns();
        let c2 = thread_cpu_ns();
        let t = Instant::now();
        publish();
        walls.push(t.elapsed().as_nanos() as f64);
        times.push((thread_cpu_ns() - c2) as f64);
        clock.push((c2 - c1) as f64);
    }
    let overhead = median(&clock);
    (times.into_iter().map(|t| (t - overhead).max(0.0)).collect(), walls)
}

fn ring_cell(nfpc: u32, ncop: u32, readers: usize, pace: &Pace) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let name = "bench-pub";
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: nfpc, chunks_on_port: ncop };
    let params = PortParams { geometry, device: "bench:publish".into(), group: None };
    let mut w = Writer::create(name, &params).expect("create port");
    let data = chunk_of(nfpc);
    for _ in 0..ncop {
        w.publish(Source::Interleaved(&data), ChunkMeta::default()).expect("publish");
    }
    let kids = spawn_ready(readers, "ring-reader", &[name.to_owned()]);
    std::thread::sleep(Duration::from_millis(20));
    let (times, walls) = time_publishes(pace, || {
        w.publish(Source::Interleaved(&data), ChunkMeta::default()).expect("publish");
    });
    w.stop();
    let reads = finish_all(kids).iter().filter_map(|l| field(l, "read_ns")).collect();
    let _ = w.remove();
    (times, walls, reads)
}

fn orig_cell(
    dir: &std::path::Path,
    nfpc: u32,
    ncop: u32,
    readers: usize,
    pace: &Pace,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let path: PathBuf = dir.join("bench-orig.port");
    let port = OrigPort::create(&path, nfpc as usize, ncop as usize);
    let kids = spawn_ready(readers, "orig-reader", &[path.display().to_string()]);
    std::thread::sleep(Duration::from_millis(20));
    let data = chunk_of(nfpc);
    let (times, walls) = time_publishes(pace, || {
        port.publish(&data);
    });
    port.stop();
    let reads = finish_all(kids).iter().filter_map(|l| field(l, "read_ns")).collect();
    drop(port);
    let _ = std::fs::remove_file(&path);
    (times, walls, reads)
}

/// How the cells of each design are paced: the ring's and the original's.
struct Paces {
    ring: Pace,
    orig: Pace,
}

/// Runs part 2.
pub fn run(reps: usize, quick: bool) -> PublishResults {
    let dir = bassport::paths::runtime_dir();
    let period = Duration::from_millis(4);
    let paces = Paces {
        ring: Pace {
            period,
            max_chunks: if quick { 50 } else { 150 },
            min_chunks: 10,
            budget: Duration::from_secs(2),
        },
        orig: Pace {
            period,
            max_chunks: if quick { 50 } else { 150 },
            min_chunks: 8,
            budget: Duration::from_millis(if quick { 800 } else { 2000 }),
        },
    };
    let mut res = PublishResults {
        cells: empty_cells(),
        period_ms: period.as_secs_f64() * 1e3,
        breakdown: breakdown(reps.max(3)),
        sweep: vec![],
    };
    for rep in 0..reps {
        for &(window_s, ncop) in WINDOWS {
            for &readers in READERS {
                for design in [Design::Ring, Design::Original] {
                    measure_cell(&mut res, rep, design, (window_s, ncop), readers, &dir, &paces);
                }
            }
        }
    }
    res.sweep = sweep(reps, &dir, &paces);
    print_summary(&res);
    res
}

/// One cell per window, reader count and design, no repetition yet.
fn empty_cells() -> Vec<PubCell> {
    let mut cells = Vec::new();
    for &(window_s, _) in WINDOWS {
        for &readers in READERS {
            for design in [Design::Ring, Design::Original] {
                cells.push(PubCell {
                    design,
                    window_s,
                    readers,
                    publish_ns: vec![],
                    publish_p90_ns: vec![],
                    wall_ns: vec![],
                    read_ns: vec![],
                    chunks: vec![],
                });
            }
        }
    }
    cells
}

/// Repetition `rep` of one cell (`design`, a window of `window_s` seconds in `ncop` chunks,
/// `readers` readers): measured, added to its cell in `res` and printed.
fn measure_cell(
    res: &mut PublishResults,
    rep: usize,
    design: Design,
    (window_s, ncop): (f64, u32),
    readers: usize,
    dir: &std::path::Path,
    paces: &Paces,
) {
    let (times, walls, reads) = match design {
        Design::Ring => ring_cell(NFPC, ncop, readers, &paces.ring),
        Design::Original => orig_cell(dir, NFPC, ncop, readers, &paces.orig),
    };
    let cell = res
        .cells
        .iter_mut()
        .find(|c| c.design == design && c.window_s == window_s && c.readers == readers)
        .expect("cell");
    cell.publish_ns.push(median(&times));
    cell.publish_p90_ns.push(quantile(&times, 0.9));
    cell.wall_ns.push(median(&walls));
    cell.read_ns.push(median(&reads));
    cell.chunks.push(times.len());
    println!(
        "  rep {} {:?} window {:>5} s readers {:>2}: publish CPU median {} p90 {}, wall {} ({} chunks), read {}",
        rep + 1,
        design,
        window_s,
        readers,
        fmt_ns(median(&times)),
        fmt_ns(quantile(&times, 0.9)),
        fmt_ns(median(&walls)),
        times.len(),
        fmt_ns(median(&reads))
    );
}

/// The chunk-size sweep at a 10 s window, one reader: the original's cost is O(window) per
/// chunk, the ring's O(chunk), so their ratio grows with nCOP.
fn sweep(reps: usize, dir: &std::path::Path, paces: &Paces) -> Vec<SweepRow> {
    let mut rows = Vec::new();
    for &nfpc in SWEEP_CHUNKS {
        let ncop = 441_000u32.div_ceil(nfpc);
        let mut row = SweepRow { frames_per_chunk: nfpc, ring_ns: vec![], orig_ns: vec![] };
        for _ in 0..reps {
            let (r, _, _) = ring_cell(nfpc, ncop, 1, &paces.ring);
            let (o, _, _) = orig_cell(dir, nfpc, ncop, 1, &paces.orig);
            row.ring_ns.push(median(&r));
            row.orig_ns.push(median(&o));
        }
        println!(
            "  10 s window, {nfpc}-frame chunks, 1 reader: ring {} original {} ratio {}",
            spread(&row.ring_ns, fmt_ns),
            spread(&row.orig_ns, fmt_ns),
            fmt_ratio(median(&row.orig_ns) / median(&row.ring_ns))
        );
        rows.push(row);
    }
    rows
}

/// Prints, per window and reader count, both designs' publish cost and their ratio.
fn print_summary(res: &PublishResults) {
    for &(window_s, _) in WINDOWS {
        for &readers in READERS {
            let r = res.cell(Design::Ring, window_s, readers).expect("cell");
            let o = res.cell(Design::Original, window_s, readers).expect("cell");
            let ratio: Vec<f64> = o.publish_ns.iter().zip(&r.publish_ns).map(|(a, b)| a / b).collect();
            println!(
                "  window {:>5} s, {:>2} readers: ring {}  original {}  original/ring {}",
                window_s,
                readers,
                spread(&r.publish_ns, fmt_ns),
                spread(&o.publish_ns, fmt_ns),
                spread(&ratio, fmt_ratio)
            );
        }
    }
}

/// Child: a bass reader blocked in `wait` that reads every chunk. Prints `read_ns=` (median
/// time of one `get_audio_data`) when the writer stops.
pub fn child_ring_reader(args: &[String]) {
    let port = Port::open(&args[0]).expect("open port");
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let cap = port.geometry().frames_per_chunk as usize * 4;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut times = Vec::new();
    crate::procs::say_ready();
    loop {
        match port.wait(nfr, Duration::from_secs(30)) {
            Ok(_) => {
                let t = Instant::now();
                let mut out = [&mut l[..], &mut r[..]];
                port.get_audio_data(cap, &mut nfr, &mut out).expect("read");
                times.push(t.elapsed().as_nanos() as f64);
            }
            Err(Error::Stopped { .. }) => break,
            Err(e) => panic!("reader: {e}"),
        }
    }
    println!("read_ns={} reads={}", median(&times), times.len());
}

/// Child: an original-design reader, woken per chunk, copying the whole port, then running
/// `getAudioData` on its copy. Prints `read_ns=` when told to stop.
pub fn child_orig_reader(args: &[String]) {
    let port = OrigPort::open(std::path::Path::new(&args[0]));
    let nfop = port.nfop();
    let mut copy = vec![1i32; 2 * nfop];
    let cap = NFPC as usize * 4;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut times = Vec::new();
    let mut seq = port.futex().load(std::sync::atomic::Ordering::Acquire);
    let mut nfr = port.read_whole(&mut copy) + 1;
    crate::procs::say_ready();
    loop {
        bassport::sys::futex_wait(port.futex(), seq, Duration::from_secs(30));
        seq = port.futex().load(std::sync::atomic::Ordering::Acquire);
        if port.stopped() {
            break;
        }
        let t = Instant::now();
        let lfi = port.read_whole(&mut copy);
        original::get_audio_data(&copy, nfop, lfi, cap, &mut nfr, &mut l, &mut r);
        times.push(t.elapsed().as_nanos() as f64);
    }
    println!("read_ns={} reads={}", median(&times), times.len());
}

/// Where a publish's time goes (no readers, 10 s window, 2205-frame chunks), in ns per chunk.
#[derive(Clone, Debug, Default)]
pub struct Breakdown {
    /// `Writer::publish` (everything).
    pub writer_publish: f64,
    /// `Ring::publish` alone on a heap window of the same size (samples + protocol words).
    pub ring_publish: f64,
    /// One FUTEX_WAKE with no waiter.
    pub futex_wake: f64,
    /// The two clock reads for the chunk's timestamps.
    pub clocks: f64,
    /// memcpy of the chunk's bytes into the window (lower bound for the data copy).
    pub memcpy_chunk: f64,
}

/// Measures the parts of a publish, interleaved, `reps` times; medians.
pub fn breakdown(reps: usize) -> Breakdown {
    use std::sync::atomic::{AtomicU32, AtomicU64};
    let ncop = 200u32;
    let nfop = (NFPC * ncop) as usize;
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: NFPC, chunks_on_port: ncop };
    let params = PortParams { geometry, device: "bench:breakdown".into(), group: None };
    let mut w = Writer::create("bench-breakdown", &params).expect("create port");
    let data = chunk();
    let heap: Vec<AtomicU64> = (0..nfop).map(|_| AtomicU64::new(0)).collect();
    let (lfi, intent) = (AtomicU64::new(0), AtomicU64::new(0));
    let ring = bassport::ring::Ring {
        last_frame_index: &lfi,
        write_intent: &intent,
        samples: &heap,
        frames_on_port: nfop as u64,
    };
    let mut plain = vec![0i32; 2 * nfop];
    let word = AtomicU32::new(0);
    let mut heap_lfi = 0u64;
    for _ in 0..ncop {
        w.publish(Source::Interleaved(&data), ChunkMeta::default()).expect("publish");
        heap_lfi = ring.publish(heap_lfi, NFPC as usize, 2, &Source::Interleaved(&data), || {});
    }
    let n = 2000usize;
    let (mut a, mut b, mut c, mut d, mut e) = (vec![], vec![], vec![], vec![], vec![]);
    let per = |f: &mut dyn FnMut(usize)| {
        let t = thread_cpu_ns();
        for k in 0..n {
            f(k);
        }
        (thread_cpu_ns() - t) as f64 / n as f64
    };
    for _ in 0..reps {
        a.push(per(&mut |_| {
            w.publish(Source::Interleaved(&data), ChunkMeta::default()).expect("publish");
        }));
        b.push(per(&mut |_| {
            heap_lfi = ring.publish(heap_lfi, NFPC as usize, 2, &Source::Interleaved(&data), || {});
        }));
        c.push(per(&mut |_| bassport::sys::futex_wake_all(&word)));
        d.push(per(&mut |_| {
            std::hint::black_box(bassport::sys::monotonic_ns() + bassport::sys::realtime_ns());
        }));
        e.push(per(&mut |k| {
            let at = (k % ncop as usize) * NFPC as usize;
            plain[at..at + NFPC as usize].copy_from_slice(&data[..NFPC as usize]);
            plain[nfop + at..nfop + at + NFPC as usize].copy_from_slice(&data[NFPC as usize..]);
            std::hint::black_box(&plain);
        }));
    }
    let _ = w.remove();
    let r = Breakdown {
        writer_publish: median(&a),
        ring_publish: median(&b),
        futex_wake: median(&c),
        clocks: median(&d),
        memcpy_chunk: median(&e),
    };
    println!(
        "  breakdown (10 s window, no reader, CPU per chunk): Writer::publish {}, Ring::publish on heap {}, FUTEX_WAKE without waiter {}, 2 clock reads {}, memcpy of the chunk {}",
        fmt_ns(r.writer_publish),
        fmt_ns(r.ring_publish),
        fmt_ns(r.futex_wake),
        fmt_ns(r.clocks),
        fmt_ns(r.memcpy_chunk)
    );
    r
}
