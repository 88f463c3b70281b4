//! Header validation under arbitrary bytes: opening a port whose header (or whole file) is
//! random or mutated never panics and never reads out of bounds; when it opens, every read
//! call stays within the mapping and returns a result.

mod common;

use bassclient::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
use proptest::prelude::*;
use std::time::Duration;

fn valid_port_bytes() -> Vec<u8> {
    let path = common::temp_port_path("fuzz-src");
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: 16, chunks_on_port: 4 };
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "fuzz".into(), group: None }).unwrap();
    for _ in 0..6 {
        w.publish(Source::Zeros, ChunkMeta::default()).unwrap();
    }
    let bytes = std::fs::read(&path).unwrap();
    w.remove().unwrap();
    bytes
}

/// Opens `bytes` as a port file and exercises every read path; must not panic.
fn exercise(bytes: &[u8]) {
    let path = common::temp_port_path("fuzz");
    std::fs::write(&path, bytes).unwrap();
    if let Ok(port) = Port::open_path(&path) {
        let mut l = vec![0; 256];
        let mut r = vec![0; 256];
        for start in [0u64, 1, 50, 95, 96, 97, u64::MAX / 2, u64::MAX] {
            let mut nfr = start;
            let channels = port.geometry().channels as usize;
            let read = if channels >= 2 {
                port.get_audio_data(256, &mut nfr, &mut [&mut l, &mut r])
            } else {
                port.get_audio_data(256, &mut nfr, &mut [&mut l])
            };
            // Whatever the header says, a read that succeeds keeps the algorithm's invariants.
            if let Ok(got) = read {
                assert!(got.frames <= 256 && got.frames as u64 <= port.frames_on_port());
                assert_eq!(nfr - start, got.frames as u64 + got.loss, "accounting");
            } else {
                assert_eq!(nfr, start, "nfr must not move on an error");
            }
            let _ = port.chunk_info(start);
            let mut nfr = start;
            if let Ok(v) = port.view(1000, &mut nfr) {
                assert!(v.frames <= 1000 && v.segments[0].1 + v.segments[1].1 == v.frames);
                assert!(port.view_overwritten(&v) <= v.frames as u64);
            }
        }
        let _ = port.info();
        let _ = port.wait(u64::MAX, Duration::ZERO);
    }
    let _ = std::fs::remove_file(&path);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn mutated_headers_never_panic(muts in proptest::collection::vec((0usize..4096, any::<u8>()), 1..24),
                                   len_cut in proptest::option::of(0usize..20000)) {
        let mut bytes = valid_port_bytes_cached().clone();
        for (off, b) in muts {
            bytes[off] = b;
        }
        if let Some(cut) = len_cut {
            bytes.truncate(cut.min(bytes.len()));
        }
        exercise(&bytes);
    }

    #[test]
    fn random_headers_never_panic(header in proptest::collection::vec(any::<u8>(), 0..4200), keep_magic in any::<bool>()) {
        let mut bytes = valid_port_bytes_cached().clone();
        let n = header.len().min(bytes.len());
        bytes[..n].copy_from_slice(&header[..n]);
        if keep_magic && bytes.len() >= 16 {
            bytes[..8].copy_from_slice(b"BASSPORT");
            bytes[8..12].copy_from_slice(&1u32.to_ne_bytes());
        }
        exercise(&bytes);
    }

    #[test]
    fn single_field_extremes_are_named_errors_or_valid(off in (0usize..256).prop_map(|o| o & !3), wide in any::<bool>(),
                                                       v in prop_oneof![Just(0u64), Just(1), Just(u64::MAX), Just(u32::MAX as u64), Just(1 << 62), any::<u64>()]) {
        let mut bytes = valid_port_bytes_cached().clone();
        if wide && off % 8 == 0 {
            bytes[off..off + 8].copy_from_slice(&v.to_ne_bytes());
        } else {
            bytes[off..off + 4].copy_from_slice(&(v as u32).to_ne_bytes());
        }
        exercise(&bytes);
    }
}

fn valid_port_bytes_cached() -> &'static Vec<u8> {
    static BYTES: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BYTES.get_or_init(valid_port_bytes)
}

#[test]
fn a_header_describing_more_than_the_file_is_refused() {
    let mut bytes = valid_port_bytes_cached().clone();
    bytes.truncate(bytes.len() - 4);
    let path = common::temp_port_path("short");
    std::fs::write(&path, &bytes).unwrap();
    let err = Port::open_path(&path).err().expect("must refuse a short file");
    assert!(matches!(err, bassclient::Error::Corrupt(_)), "{err}");
    let _ = std::fs::remove_file(&path);
}
