//! Read throughput of a 1-second stereo block (44.1 kHz) through `get_audio_data`, against
//! memcpy of the same bytes, measured side by side in one run (medians of 31 runs).
//! `cargo run --release -p bassport --example read_throughput`

use std::time::Instant;

use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

fn main() {
    let path = std::env::temp_dir().join(format!("bass-throughput-{}.port", std::process::id()));
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: 2205, chunks_on_port: 40 };
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "bench".into(), group: None }).unwrap();
    let chunk: Vec<i32> = (0..2205 * 2).collect();
    for _ in 0..40 {
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
    }
    let port = Port::open_path(&path).unwrap();
    let n = 44100usize;
    let bytes = (n * 2 * 4) as f64;
    let (mut l, mut r) = (vec![0i32; n], vec![0i32; n]);
    let src_l: Vec<i32> = (0..n as i32).collect();
    let src_r: Vec<i32> = (0..n as i32).collect();
    let (mut ring_t, mut copy_t) = (Vec::new(), Vec::new());
    for _ in 0..31 {
        let t = Instant::now();
        let mut nfr = w.last_frame_index() - n as u64 + 1;
        let got = port.get_audio_data(n, &mut nfr, &mut [&mut l, &mut r]).unwrap();
        ring_t.push(t.elapsed().as_secs_f64());
        assert_eq!(got.frames, n);
        let t = Instant::now();
        l.copy_from_slice(std::hint::black_box(&src_l));
        r.copy_from_slice(std::hint::black_box(&src_r));
        copy_t.push(t.elapsed().as_secs_f64());
        std::hint::black_box((&l, &r));
    }
    let (ring, copy) = (median(ring_t), median(copy_t));
    println!(
        "1 s stereo block ({} KiB): get_audio_data {:.2} GB/s, memcpy {:.2} GB/s, ratio {:.2}x",
        bytes as usize / 1024,
        bytes / ring / 1e9,
        bytes / copy / 1e9,
        copy / ring
    );
    w.remove().unwrap();
}
