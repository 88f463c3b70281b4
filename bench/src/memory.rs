//! Part 6: memory. The port file is the header, the chunk tables and the window, nothing
//! more; resident memory of a writer and of readers, against the original design, where
//! every reader holds a private copy of the whole port.

use std::os::unix::fs::MetadataExt;
use std::time::{Duration, Instant};

use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, Writer};

use crate::original::{self, OrigPort};
use crate::procs::{field, rss_of, spawn_ready, Child, Rss};

/// Windows measured: (seconds, chunks of 2205 frames).
pub const WINDOWS: &[(f64, u32)] = &[(1.0, 20), (10.0, 200), (60.0, 1200)];

/// The measured port's geometry: 44.1 kHz stereo, `ncop` chunks of 2205 frames.
pub fn geometry(ncop: u32) -> Geometry {
    Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: 2205, chunks_on_port: ncop }
}

/// One window's numbers.
#[derive(Clone, Debug)]
pub struct MemRow {
    /// Window in seconds.
    pub window_s: f64,
    /// Chunks on the port (nCOP).
    pub chunks: u32,
    /// Window bytes: channels * nFOP * 4.
    pub window_bytes: u64,
    /// Port file size.
    pub file_bytes: u64,
    /// Bytes allocated for the file (st_blocks * 512) once the window is full.
    pub allocated_bytes: u64,
    /// Header + chunk table + chunk extension table bytes (file - window).
    pub overhead_bytes: u64,
    /// The writer process (publishing).
    pub writer: Rss,
    /// A reader that reads every new chunk.
    pub tail_reader: Rss,
    /// A reader that reads the whole window each time.
    pub full_reader: Rss,
    /// An original-design reader (private copy of the whole port).
    pub orig_reader: Rss,
    /// A process of this binary that has not opened any port (baseline).
    pub baseline: Rss,
}

/// Runs part 6.
pub fn run() -> Vec<MemRow> {
    let mut rows = Vec::new();
    for &(window_s, ncop) in WINDOWS {
        let name = format!("bench-mem-{ncop}");
        let mut writer = Child::spawn("mem-writer", &[name.clone(), ncop.to_string(), "1500".into()]);
        let info = writer.line();
        writer.ready();
        let mut readers = spawn_ready(1, "mem-reader", &[name.clone(), "tail".into()]);
        readers.extend(spawn_ready(1, "mem-reader", &[name.clone(), "full".into()]));
        let opath = bassport::paths::runtime_dir().join(format!("bench-mem-orig-{ncop}"));
        let oport = OrigPort::create(&opath, 2205, ncop as usize);
        let orig = Child::spawn("mem-orig-reader", &[opath.display().to_string()]);
        let mut wlines = writer.finish();
        wlines.retain(|l| l.starts_with("rss="));
        let rl: Vec<Vec<String>> = readers.into_iter().map(Child::finish).collect();
        let ol = orig.finish();
        drop(oport);
        let _ = std::fs::remove_file(&opath);
        let g = |k| field(&info, k).unwrap_or(0.0) as u64;
        let pick = |lines: &[String], prefix: &str| {
            lines.iter().find_map(|l| l.strip_prefix(prefix)).map(Rss::parse).unwrap_or_default()
        };
        let row = MemRow {
            window_s,
            chunks: ncop,
            window_bytes: g("window"),
            file_bytes: g("file"),
            allocated_bytes: g("allocated"),
            overhead_bytes: g("file") - g("window"),
            writer: wlines.first().map(|l| Rss::parse(l)).unwrap_or_default(),
            tail_reader: pick(&rl[0], "after "),
            full_reader: pick(&rl[1], "after "),
            orig_reader: pick(&ol, "after "),
            baseline: pick(&rl[0], "before "),
        };
        println!(
            "  window {window_s:>4} s: window {} B, file {} B (header + chunk tables {} B), allocated {} B; RSS KiB: writer {} / tail reader {} (shm {}) / full reader {} (shm {}) / original reader {} (anon {}) / baseline {}",
            row.window_bytes,
            row.file_bytes,
            row.overhead_bytes,
            row.allocated_bytes,
            row.writer.rss,
            row.tail_reader.rss,
            row.tail_reader.shmem,
            row.full_reader.rss,
            row.full_reader.shmem,
            row.orig_reader.rss,
            row.orig_reader.anon,
            row.baseline.rss
        );
        rows.push(row);
    }
    rows
}

/// Child: creates a port, fills its window, reports the sizes, then publishes a chunk every
/// 5 ms for the given milliseconds and reports its own RSS.
pub fn child_writer(args: &[String]) {
    let name = &args[0];
    let ncop: u32 = args[1].parse().expect("ncop");
    let ms: u64 = args[2].parse().expect("ms");
    let params = PortParams { geometry: geometry(ncop), device: "bench:memory".into(), group: None };
    let mut w = Writer::create(name, &params).expect("create port");
    let data: Vec<i32> = (0..4410).collect();
    for _ in 0..ncop {
        w.publish(Source::Interleaved(&data), ChunkMeta::default()).expect("publish");
    }
    let meta = std::fs::metadata(w.path()).expect("stat port");
    let window = 2 * 4 * u64::from(ncop) * 2205;
    println!("window={window} file={} allocated={}", meta.len(), meta.blocks() * 512);
    crate::procs::say_ready();
    let start = Instant::now();
    while start.elapsed() < Duration::from_millis(ms) {
        std::thread::sleep(Duration::from_millis(5));
        w.publish(Source::Interleaved(&data), ChunkMeta::default()).expect("publish");
    }
    let rss = rss_of("self");
    let _ = w.remove();
    println!("{}", rss.words());
}

/// Child: a reader; `tail` reads every new chunk, `full` reads the whole window each chunk.
pub fn child_reader(args: &[String]) {
    let before = rss_of("self");
    let port = Port::open(&args[0]).expect("open port");
    let full = args[1] == "full";
    let nfop = port.frames_on_port() as usize;
    let cap = if full { nfop } else { port.geometry().frames_per_chunk as usize * 4 };
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    crate::procs::say_ready();
    loop {
        match port.wait(nfr, Duration::from_secs(30)) {
            Ok(lfi) => {
                if full {
                    nfr = (lfi + 1).saturating_sub(nfop as u64);
                }
                let mut bufs = [&mut l[..], &mut r[..]];
                port.get_audio_data(cap, &mut nfr, &mut bufs).expect("read");
            }
            Err(Error::Stopped { .. }) => break,
            Err(e) => panic!("memory reader: {e}"),
        }
    }
    let after = rss_of("self");
    println!("before {}", before.words());
    println!("after {}", after.words());
}

/// Child: an original-design reader: copies the whole port, then reads the newest chunk.
pub fn child_orig_reader(args: &[String]) {
    let port = OrigPort::open(std::path::Path::new(&args[0]));
    let nfop = port.nfop();
    let mut copy = vec![0i32; 2 * nfop];
    let (mut l, mut r) = (vec![0i32; 2205], vec![0i32; 2205]);
    for _ in 0..3 {
        let lfi = port.read_whole(&mut copy);
        let mut nfr = lfi - 2204;
        original::get_audio_data(&copy, nfop, lfi, 2205, &mut nfr, &mut l, &mut r);
        std::thread::sleep(Duration::from_millis(20));
    }
    println!("after {}", rss_of("self").words());
}
