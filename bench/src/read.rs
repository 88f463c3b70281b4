//! Part 1: `bass_get_audio_data` throughput against memcpy of the same bytes.
//!
//! One port of 44.1 kHz stereo holding a little more than 10 s, filled once. For each
//! block size the newest N frames are read again and again, alternating, in the same run:
//! (a) the C ABI `bass_get_audio_data`, (b) the Rust `Port::get_audio_data`,
//! (c) `memcpy` of exactly the same ring segments into the same buffers; (a) and (c) in the
//! order a c c a over the two halves of a sample's blocks, which cancels what the call before
//! leaves behind (a cache or frequency state) and a drift during the sample.
//! No writer runs during the measurement, so the plain memcpy of (c) is race-free here;
//! (a) and (b) take the race-free path they always take (Relaxed atomic loads + intent re-check).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use bassport::ring::{copy_path, set_copy_path, CopyPath};
use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};

use crate::stats::{median, spread};

/// Block sizes measured (frames at 44.1 kHz) and their labels.
pub const BLOCKS: &[(usize, &str)] = &[
    (44, "1 ms"),
    (441, "10 ms"),
    (4410, "100 ms"),
    (8192, "186 ms (64 KiB)"),
    (44100, "1 s"),
    (441000, "10 s"),
];

/// One block size's results.
#[derive(Clone, Debug)]
pub struct ReadRow {
    /// Frames per block.
    pub frames: usize,
    /// Label.
    pub label: &'static str,
    /// Bytes per block (both channels).
    pub bytes: usize,
    /// Per repetition, hot (the same block read again and again, source in L1/L2):
    /// GB/s of the C ABI call.
    pub ffi_gbs: Vec<f64>,
    /// Per repetition, hot: GB/s of the Rust call.
    pub rust_gbs: Vec<f64>,
    /// Per repetition, hot: GB/s of memcpy.
    pub memcpy_gbs: Vec<f64>,
    /// Per repetition, hot: memcpy time / C ABI time.
    pub ratio: Vec<f64>,
    /// Per repetition, hot: time of one C ABI call (ns).
    pub ffi_call_ns: Vec<f64>,
    /// Per repetition, streaming (successive blocks across the 10 s window): C ABI GB/s.
    pub stream_ffi_gbs: Vec<f64>,
    /// Per repetition, streaming: memcpy GB/s.
    pub stream_memcpy_gbs: Vec<f64>,
    /// Per repetition, streaming: memcpy time / C ABI time.
    pub stream_ratio: Vec<f64>,
}

impl ReadRow {
    /// Median ratio C ABI / memcpy (hot).
    pub fn ratio_median(&self) -> f64 {
        median(&self.ratio)
    }

    /// Median ratio C ABI / memcpy (streaming).
    pub fn stream_ratio_median(&self) -> f64 {
        median(&self.stream_ratio)
    }
}

/// The copy paths this CPU has that copy wider than a word (the ones part 1 compares).
pub fn wide_paths() -> Vec<CopyPath> {
    let auto = copy_path();
    let paths =
        CopyPath::ALL.into_iter().filter(|&p| p != CopyPath::Portable && set_copy_path(p).is_ok()).collect();
    set_copy_path(auto).expect("the chosen path");
    paths
}

/// Part 1's reads, by copy path.
#[derive(Clone, Debug, Default)]
pub struct ReadResults {
    /// The path the library chose on this CPU (the one every other part runs).
    pub chosen: Option<CopyPath>,
    /// Each wide path's rows, measured in the same repetitions (interleaved).
    pub by_path: Vec<(CopyPath, Vec<ReadRow>)>,
}

impl ReadResults {
    /// The rows of the chosen path.
    pub fn chosen_rows(&self) -> &[ReadRow] {
        self.by_path.iter().find(|(p, _)| Some(*p) == self.chosen).map_or(&[], |(_, rows)| rows.as_slice())
    }
}

/// Copy-loop experiment: the same 64 KiB copied by memcpy, by the library's ring copy
/// (`ChannelRing::copy_to`) on each wide path, and by a loop of Relaxed `AtomicU64` loads
/// (the portable path, used where there is no wide copy); memcpy and the ring copies also with
/// the destination placed 16 bytes past the source modulo 4 KiB ([`ALIASED`]).
#[derive(Clone, Debug, Default)]
pub struct CopyLoops {
    /// Per repetition GB/s: memcpy.
    pub memcpy: Vec<f64>,
    /// Per wide path, per repetition GB/s: the library's ring copy.
    pub ring: Vec<(CopyPath, Vec<f64>)>,
    /// Per repetition GB/s: AtomicU64 loop.
    pub atomic64: Vec<f64>,
    /// Per repetition GB/s: memcpy, destination 4 KiB-aliased with the source.
    pub aliased_memcpy: Vec<f64>,
    /// Per wide path, per repetition GB/s: the ring copy, destination 4 KiB-aliased.
    pub aliased_ring: Vec<(CopyPath, Vec<f64>)>,
}

/// Distance (bytes, modulo 4 KiB) from the source to the destination in the copy loops: far
/// apart, and the 4 KiB-aliased case where a fast-string `rep movsb` (glibc's memcpy from
/// 2 KiB up on CPUs with ERMS) slows down on some CPUs (AMD Zen 3: glibc bug 30994).
pub const FAR: usize = 2048;
/// See [`FAR`].
pub const ALIASED: usize = 16;

fn time_per_iter(iters: usize, mut f: impl FnMut(usize)) -> f64 {
    let t = Instant::now();
    for k in 0..iters {
        f(k);
    }
    t.elapsed().as_nanos() as f64 / iters as f64
}

/// Ring segments (start slot, length) of `n` frames from `first` in a ring of `nfop`.
fn segments(first: u64, n: usize, nfop: u64) -> [(usize, usize); 2] {
    let start = ((first - 1) % nfop) as usize;
    let len0 = n.min(nfop as usize - start);
    [(start, len0), (0, n - len0)]
}

/// Runs the copy-loop experiment.
pub fn copy_loops(reps: usize) -> CopyLoops {
    let n = 16384; // 64 KiB of i32
    let src64: Vec<AtomicU64> = (0..n as u64 / 2).map(AtomicU64::new).collect();
    let (lfi, intent) = (AtomicU64::new(0), AtomicU64::new(0));
    let ring = bassport::ring::Ring {
        last_frame_index: &lfi,
        write_intent: &intent,
        samples: &src64,
        frames_on_port: n as u64,
    };
    let ring = ring.channel(0);
    // The destinations: `n` samples at a chosen distance from the source modulo 4 KiB.
    let mut buf = vec![0i32; n + 2048];
    let at = |buf: &[i32], distance: usize| {
        let (src, base) = (src64.as_ptr() as usize, buf.as_ptr() as usize);
        (src + distance + 4096 - base % 4096) % 4096 / 4
    };
    let (far, aliased) = (at(&buf, FAR), at(&buf, ALIASED));
    let mut dst64 = vec![0u64; n / 2];
    let iters = 4000;
    let auto = copy_path();
    let paths = || wide_paths().into_iter().map(|p| (p, vec![])).collect();
    let mut out = CopyLoops { ring: paths(), aliased_ring: paths(), ..Default::default() };
    let gbs = |ns: f64| (n * 4) as f64 / ns;
    for _ in 0..reps {
        for (off, memcpy, rings) in
            [(far, &mut out.memcpy, &mut out.ring), (aliased, &mut out.aliased_memcpy, &mut out.aliased_ring)]
        {
            let dst = &mut buf[off..off + n];
            let m = time_per_iter(iters, |_| {
                // SAFETY: `src64` holds `n` samples (n / 2 words) and is only read (no thread
                // writes it); `dst` holds `n` samples; the two do not overlap.
                unsafe { std::ptr::copy_nonoverlapping(src64.as_ptr() as *const i32, dst.as_mut_ptr(), n) };
                std::hint::black_box(&dst);
            });
            memcpy.push(gbs(m));
            for (path, v) in rings.iter_mut() {
                set_copy_path(*path).expect("a path of this CPU");
                let a = time_per_iter(iters, |_| {
                    ring.copy_to(0, dst);
                    std::hint::black_box(&dst);
                });
                v.push(gbs(a));
            }
            set_copy_path(auto).expect("the chosen path");
        }
        let b = time_per_iter(iters, |_| {
            for (d, s) in dst64.iter_mut().zip(&src64) {
                *d = s.load(Ordering::Relaxed);
            }
            std::hint::black_box(&dst64);
        });
        out.atomic64.push(gbs(b));
    }
    let rings = |r: &[(CopyPath, Vec<f64>)]| {
        r.iter()
            .map(|(p, v)| format!("{} {} GB/s", p.name(), spread(v, |v| format!("{v:.1}"))))
            .collect::<Vec<_>>()
    };
    println!(
        "  copy loops, 64 KiB hot: memcpy {} GB/s, the ring copy {}, Relaxed AtomicU64 loads {} GB/s; destination {ALIASED} B past the source mod 4 KiB: memcpy {} GB/s, the ring copy {}",
        spread(&out.memcpy, |v| format!("{v:.1}")),
        rings(&out.ring).join(", "),
        spread(&out.atomic64, |v| format!("{v:.1}")),
        spread(&out.aliased_memcpy, |v| format!("{v:.1}")),
        rings(&out.aliased_ring).join(", "),
    );
    out
}

/// The port of part 1: filled and wrapped, open both through the C ABI and in Rust, idle while
/// measured.
struct Filled {
    w: Writer,
    port: Port,
    handle: *mut bassclient::bass_port,
    /// Each channel's ring of `nfop` samples in the mapping.
    rings: Vec<*const i32>,
    /// The newest frame on the port.
    lfi: u64,
    /// Frames on the port.
    nfop: u64,
}

impl Filled {
    /// Creates the port (441-frame chunks, 1001 of them), fills the window and goes once more
    /// around so that the ring wraps, and opens it twice.
    fn create() -> Filled {
        let nfpc = 441u32;
        let ncop = 1001u32;
        let geometry =
            Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: nfpc, chunks_on_port: ncop };
        let params = PortParams { geometry, device: "bench:read".into(), group: None };
        let mut w = Writer::create("bench-read", &params).expect("create port");
        let chunk: Vec<i32> = (0..nfpc as i32 * 2).map(|i| i.wrapping_mul(7919)).collect();
        // Fill the window, and go once more around so that the ring wraps.
        for _ in 0..ncop + ncop / 3 {
            w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).expect("publish");
        }
        let lfi = w.last_frame_index();
        let nfop = u64::from(nfpc * ncop);
        let port = Port::open("bench-read").expect("open port");
        let cname = std::ffi::CString::new("bench-read").expect("name");
        let mut handle: *mut bassclient::bass_port = std::ptr::null_mut();
        // SAFETY: a valid C string and a valid out-pointer.
        let rc = unsafe { bassclient::bass_port_open(cname.as_ptr(), &mut handle) };
        assert_eq!(rc as i32, 0, "bass_port_open");
        let rings: Vec<*const i32> =
            (0..2).map(|c| port.channel_ring(c).expect("channel").as_ptr()).collect();
        Filled { w, port, handle, rings, lfi, nfop }
    }

    /// Closes both handles and removes the port.
    fn close(self) {
        // SAFETY: `handle` came from bass_port_open and is closed once.
        unsafe { bassclient::bass_port_close(self.handle) };
        drop(self.port);
        let _ = self.w.remove();
    }
}

/// Runs part 1 with `reps` repetitions: every wide copy path of this CPU, interleaved (each
/// repetition measures every block size on one path, then on the next).
pub fn run(reps: usize) -> ReadResults {
    let filled = Filled::create();
    let max = BLOCKS.iter().map(|b| b.0).max().unwrap_or(1);
    let mut left = vec![0i32; max];
    let mut right = vec![0i32; max];
    let chosen = copy_path();
    let mut out = ReadResults {
        chosen: Some(chosen),
        by_path: wide_paths().into_iter().map(|p| (p, new_rows())).collect(),
    };
    for _ in 0..reps {
        for (path, rows) in out.by_path.iter_mut() {
            set_copy_path(*path).expect("a path of this CPU");
            for row in rows.iter_mut() {
                measure(&filled, row, &mut left, &mut right);
            }
        }
    }
    set_copy_path(chosen).expect("the chosen path");
    filled.close();
    for (path, rows) in &out.by_path {
        println!("  copy path {}{}:", path.name(), if *path == chosen { " (chosen)" } else { "" });
        print_rows(rows);
    }
    out
}

/// A row per block size, nothing measured yet.
fn new_rows() -> Vec<ReadRow> {
    BLOCKS
        .iter()
        .map(|&(frames, label)| ReadRow {
            frames,
            label,
            bytes: frames * 8,
            ffi_gbs: vec![],
            rust_gbs: vec![],
            memcpy_gbs: vec![],
            ratio: vec![],
            ffi_call_ns: vec![],
            stream_ffi_gbs: vec![],
            stream_memcpy_gbs: vec![],
            stream_ratio: vec![],
        })
        .collect()
}

/// One repetition for `row`'s block size: hot (always the newest block) then streaming
/// (successive blocks through the newest 10 s), the C ABI against memcpy of the same
/// segments, and hot also the Rust call. `left` and `right` hold at least `row.frames` samples.
fn measure(filled: &Filled, row: &mut ReadRow, left: &mut [i32], right: &mut [i32]) {
    let Filled { port, handle, rings, lfi, nfop, .. } = filled;
    let (handle, lfi, nfop) = (*handle, *lfi, *nfop);
    let n = row.frames;
    // ~32 MB copied per timing sample, at least 6 calls (an even count: see below).
    let iters = (32_000_000 / row.bytes).clamp(6, 200_000) & !1;
    let half = iters / 2;
    // Hot: always the newest n frames. Streaming: successive blocks through the
    // newest 10 s, as a reader consuming a stream (source mostly not in L1/L2).
    let oldest = lfi - 441_000 + 1;
    let span = 441_000 - n as u64 + 1;
    let starts: Vec<u64> = (0..iters as u64).map(|k| oldest + (k * n as u64) % span).collect();
    let hot: Vec<u64> = vec![lfi - n as u64 + 1; iters];
    for (stream, firsts) in [(false, &hot), (true, &starts)] {
        let (lp, rp) = (left.as_mut_ptr(), right.as_mut_ptr());
        let segs: Vec<[(usize, usize); 2]> = firsts.iter().map(|&f| segments(f, n, nfop)).collect();
        let ffi = |k: usize| {
            let mut nfr = firsts[k];
            let (mut got, mut loss) = (0usize, 0u64);
            // SAFETY: `handle` is open; both buffers hold at least `n` samples; the
            // out-pointers are valid locals.
            let rc =
                unsafe { bassclient::bass_get_audio_data(handle, n, &mut nfr, lp, rp, &mut got, &mut loss) };
            assert!(rc as i32 == 0 && got == n && loss == 0);
        };
        let memcpy = |k: usize| {
            for (c, dst) in [lp, rp].into_iter().enumerate() {
                let mut done = 0;
                for &(s, len) in &segs[k] {
                    // SAFETY: the segments lie inside channel c's ring of nFOP samples;
                    // `dst` holds at least `n` samples and does not overlap the mapping. No
                    // process writes the port during this measurement (its only writer is
                    // `filled.w`, idle in this thread), so this plain copy races with nothing.
                    unsafe { std::ptr::copy_nonoverlapping(rings[c].add(s), dst.add(done), len) };
                    done += len;
                }
            }
            std::hint::black_box(lp);
        };
        ffi(0);
        memcpy(0);
        if stream {
            // One untimed pass over every block first: the window (3.5 MB) is then in the
            // last-level cache for both sides, as a window the writer has just written is.
            // Without it the first side timed paid for bringing it in: bass went first and
            // measured 0.61-0.95x memcpy streaming, and 1.01-1.22x with the order swapped
            // (three quick runs each way, AMD EPYC, 2026-12-07).
            (0..iters).for_each(memcpy);
        }
        // In the order A B B A over the two halves of the blocks, so that neither call has
        // the place right after the other's (a cache or frequency state left by the one before
        // counts for both, and a drift during the sample cancels).
        let ffi_ns = time_per_iter(half, ffi);
        let memcpy_ns = time_per_iter(half, memcpy) + time_per_iter(half, |k| memcpy(half + k));
        let ffi_ns = (ffi_ns + time_per_iter(half, |k| ffi(half + k))) / 2.0;
        let memcpy_ns = memcpy_ns / 2.0;
        let gbs = |ns: f64| row.bytes as f64 / ns;
        if stream {
            row.stream_ffi_gbs.push(gbs(ffi_ns));
            row.stream_memcpy_gbs.push(gbs(memcpy_ns));
            row.stream_ratio.push(memcpy_ns / ffi_ns);
            continue;
        }
        let mut rust = |k: usize| {
            let mut nfr = firsts[k];
            let mut out = [&mut left[..n], &mut right[..n]];
            let r = port.get_audio_data(n, &mut nfr, &mut out).expect("read");
            assert_eq!(r.frames, n);
        };
        rust(0);
        let rust_ns = time_per_iter(iters, &mut rust);
        row.ffi_gbs.push(gbs(ffi_ns));
        row.rust_gbs.push(gbs(rust_ns));
        row.memcpy_gbs.push(gbs(memcpy_ns));
        row.ratio.push(memcpy_ns / ffi_ns);
        row.ffi_call_ns.push(ffi_ns);
    }
}

/// Prints each block size's results, their spread over the repetitions.
fn print_rows(rows: &[ReadRow]) {
    for r in rows {
        println!(
            "  read {:>16} {:>8} B: hot: bass_get_audio_data {} GB/s, Port::get_audio_data {} GB/s, memcpy {} GB/s, ratio {}; streaming: {} vs {} GB/s, ratio {}",
            r.label,
            r.bytes,
            spread(&r.ffi_gbs, |v| format!("{v:.2}")),
            spread(&r.rust_gbs, |v| format!("{v:.2}")),
            spread(&r.memcpy_gbs, |v| format!("{v:.2}")),
            spread(&r.ratio, |v| format!("{v:.2}")),
            spread(&r.stream_ffi_gbs, |v| format!("{v:.2}")),
            spread(&r.stream_memcpy_gbs, |v| format!("{v:.2}")),
            spread(&r.stream_ratio, |v| format!("{v:.2}")),
        );
    }
}

/// The per-call cost of `bass_port_get_info` (which answers whether the writer lives, from a
/// pidfd opened once) against `bass_get_audio_data` of one chunk, and against the /proc read
/// every info call made before (`sys::writer_alive`: open, read and parse /proc/PID/stat).
#[derive(Clone, Debug, Default)]
pub struct InfoCost {
    /// Per repetition: ns per `bass_port_get_info`.
    pub info_ns: Vec<f64>,
    /// Per repetition: ns per `bass_get_audio_data` of one 441-frame chunk (hot).
    pub read_chunk_ns: Vec<f64>,
    /// Per repetition: ns per /proc liveness read (the former per-call cost).
    pub proc_ns: Vec<f64>,
    /// Per repetition: ns per `bass_get_audio_data` of one frame (the per-call cost).
    pub ffi_one_ns: Vec<f64>,
    /// Per repetition: ns per `Port::get_audio_data` of one frame (the read without the C ABI
    /// layer: no handle lookup, argument checks or panic boundary).
    pub rust_one_ns: Vec<f64>,
}

/// Measures [`InfoCost`], the three alternating in each repetition.
pub fn info_cost(reps: usize) -> InfoCost {
    let nfpc = 441u32;
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: nfpc, chunks_on_port: 100 };
    let params = PortParams { geometry, device: "bench:info".into(), group: None };
    let mut w = Writer::create("bench-info", &params).expect("create port");
    let chunk = vec![1i32; nfpc as usize * 2];
    for _ in 0..10 {
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).expect("publish");
    }
    let lfi = w.last_frame_index();
    let cname = std::ffi::CString::new("bench-info").expect("name");
    let mut handle: *mut bassclient::bass_port = std::ptr::null_mut();
    // SAFETY: a valid C string and a valid out-pointer.
    let rc = unsafe { bassclient::bass_port_open(cname.as_ptr(), &mut handle) };
    assert_eq!(rc as i32, 0, "bass_port_open");
    let (mut left, mut right) = (vec![0i32; nfpc as usize], vec![0i32; nfpc as usize]);
    let (pid, start) = (std::process::id(), bassport::sys::own_start_time());
    let port = Port::open("bench-info").expect("open port");
    let mut out = InfoCost::default();
    for _ in 0..reps {
        out.ffi_one_ns.push(time_per_iter(200_000, |_| {
            let (mut nfr, mut got, mut loss) = (lfi, 0usize, 0u64);
            // SAFETY: `handle` is open; both buffers hold nfpc >= 1 samples; valid out-pointers.
            let rc = unsafe {
                bassclient::bass_get_audio_data(
                    handle,
                    1,
                    &mut nfr,
                    left.as_mut_ptr(),
                    right.as_mut_ptr(),
                    &mut got,
                    &mut loss,
                )
            };
            assert!(rc as i32 == 0 && got == 1);
        }));
        out.rust_one_ns.push(time_per_iter(200_000, |_| {
            let mut nfr = lfi;
            let mut dst = [&mut left[..1], &mut right[..1]];
            assert_eq!(port.get_audio_data(1, &mut nfr, &mut dst).expect("read").frames, 1);
        }));
        let mut info = std::mem::MaybeUninit::<bassclient::bass_port_info>::uninit();
        out.info_ns.push(time_per_iter(20_000, |_| {
            // SAFETY: `handle` is open; `info` is valid for a write.
            let rc = unsafe { bassclient::bass_port_get_info(handle, info.as_mut_ptr()) };
            assert_eq!(rc as i32, 0);
        }));
        out.read_chunk_ns.push(time_per_iter(20_000, |_| {
            let (mut nfr, mut got, mut loss) = (lfi - u64::from(nfpc) + 1, 0usize, 0u64);
            // SAFETY: `handle` is open; both buffers hold nfpc samples; valid out-pointers.
            let rc = unsafe {
                bassclient::bass_get_audio_data(
                    handle,
                    nfpc as usize,
                    &mut nfr,
                    left.as_mut_ptr(),
                    right.as_mut_ptr(),
                    &mut got,
                    &mut loss,
                )
            };
            assert!(rc as i32 == 0 && got == nfpc as usize);
        }));
        out.proc_ns.push(time_per_iter(2_000, |_| {
            assert!(bassport::sys::writer_alive(pid, start));
        }));
    }
    // SAFETY: `handle` came from bass_port_open and is closed once.
    unsafe { bassclient::bass_port_close(handle) };
    drop(port);
    let _ = w.remove();
    println!(
        "  per call: bass_get_audio_data of one frame {} ns, Port::get_audio_data of one frame {} ns",
        spread(&out.ffi_one_ns, |v| format!("{v:.0}")),
        spread(&out.rust_one_ns, |v| format!("{v:.0}")),
    );
    println!(
        "  info: bass_port_get_info {} ns per call, bass_get_audio_data of one 441-frame chunk {} ns, the /proc liveness read it made before {} ns",
        spread(&out.info_ns, |v| format!("{v:.0}")),
        spread(&out.read_chunk_ns, |v| format!("{v:.0}")),
        spread(&out.proc_ns, |v| format!("{v:.0}")),
    );
    out
}
