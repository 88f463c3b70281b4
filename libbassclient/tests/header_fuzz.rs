//! Header validation under arbitrary bytes: opening a port whose header (or whole file) is
//! random or mutated never panics and never reads out of bounds; when it opens, every read
//! call stays within the mapping and returns a result.
//!
//! Random headers that keep the magic and the current version (`format::VERSION_MAJOR`, not a
//! literal: a header of another major is refused before any other field is read) reach the
//! deeper checks; [`random_headers_reach_every_check_past_the_version`] counts which.

use bass_test_support::client as common;

use bassport::format::{self, HEADER_SIZE, VERSION_MAJOR, VERSION_MINOR};
use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, Writer};
use proptest::prelude::*;
use std::collections::BTreeMap;
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

/// Opens `bytes` as a port file and exercises every read path; must not panic. Returns how
/// the open ended.
fn exercise(bytes: &[u8]) -> Result<(), Error> {
    let path = common::temp_port_path("fuzz");
    std::fs::write(&path, bytes).unwrap();
    let opened = Port::open_path(&path);
    if let Ok(port) = &opened {
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
    std::fs::remove_file(&path).unwrap();
    opened.map(drop)
}

/// How much of a valid header a random one keeps, field group by field group in the order
/// `format::validate` checks them: each level gets one check further.
const KEEP_NOTHING: u8 = 0;
/// Magic and the current version: past the version check, refused by `header_size`.
const KEEP_VERSION: u8 = 1;
/// ... and `header_size`, `sample_format`: refused by the geometry.
const KEEP_FORMAT: u8 = 2;
/// ... and the geometry: refused by the stored offsets.
const KEEP_GEOMETRY: u8 = 3;
/// ... and the offsets: a valid header with random state, indices and counters, which opens.
const KEEP_LAYOUT: u8 = 4;

/// A valid port whose first bytes are replaced by `header`, then the fields of `keep`
/// restored from the valid port.
fn random_header(header: &[u8], keep: u8) -> Vec<u8> {
    let valid = valid_port_bytes_cached();
    let mut bytes = valid.clone();
    let n = header.len().min(bytes.len());
    bytes[..n].copy_from_slice(&header[..n]);
    let restore = |bytes: &mut Vec<u8>, range: std::ops::Range<usize>| {
        if bytes.len() >= range.end {
            bytes[range.clone()].copy_from_slice(&valid[range]);
        }
    };
    if keep >= KEEP_VERSION {
        bytes[..8].copy_from_slice(&format::MAGIC.to_ne_bytes());
        bytes[8..12].copy_from_slice(&VERSION_MAJOR.to_ne_bytes());
        bytes[12..16].copy_from_slice(&VERSION_MINOR.to_ne_bytes());
    }
    if keep >= KEEP_FORMAT {
        restore(&mut bytes, 16..20); // header_size
        restore(&mut bytes, 24..28); // sample_format
    }
    if keep >= KEEP_GEOMETRY {
        restore(&mut bytes, 20..24); // channels
        restore(&mut bytes, 28..40); // sample rate, nFPC, nCOP
    }
    if keep >= KEEP_LAYOUT {
        restore(&mut bytes, 40..64); // chunk table, samples, total size
        restore(&mut bytes, 120..128); // the extension table (format 2.4)
    }
    bytes
}

/// Which check refused a header kept to level `keep` (or "opened"); panics on a refusal that
/// a header with the magic and the current version must never get.
fn refused_by(outcome: &Result<(), Error>, keep: u8) -> &'static str {
    match outcome {
        Ok(()) => "opened",
        Err(Error::Corrupt(m)) if m.starts_with("header_size") => "header_size",
        Err(Error::Corrupt(m)) if m.starts_with("sample_format") => "sample_format",
        Err(Error::Corrupt(m)) if m.starts_with("geometry") => "geometry",
        Err(Error::Corrupt(m)) if m.starts_with("offsets") => "offsets",
        Err(Error::Corrupt(m)) if m.starts_with("ext_table_offset") => "ext_table_offset",
        Err(Error::Corrupt(m)) if m.contains("truncated") => "file length",
        Err(
            e @ (Error::Incompatible { .. }
            | Error::BadMagic { .. }
            | Error::NotReady
            | Error::NeverReady { .. }),
        ) if keep >= KEEP_VERSION => {
            panic!("a header with the magic and version {VERSION_MAJOR}.{VERSION_MINOR} was refused before the version check passed: {e}")
        }
        Err(_) => "before the version",
    }
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
        // Any outcome but a panic: mutations anywhere in the file may leave it valid.
        drop(exercise(&bytes));
    }

    #[test]
    fn random_headers_never_panic(header in proptest::collection::vec(any::<u8>(), 0..4200),
                                  keep in KEEP_NOTHING..=KEEP_LAYOUT) {
        // Kept to the version or further, it is judged on its fields (refused_by panics if not).
        refused_by(&exercise(&random_header(&header, keep)), keep);
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
        // Any outcome but a panic: mutations anywhere in the file may leave it valid.
        drop(exercise(&bytes));
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
    assert!(matches!(err, bassport::Error::Corrupt(_)), "{err}");
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn random_headers_reach_every_check_past_the_version() {
    // 200 random headers (whole 4096-byte pages) per level: each level reaches the check
    // after the fields it keeps. Were the kept version not the current one, every level
    // would stop at the version check.
    let mut rng = fastrand::Rng::with_seed(22);
    let mut seen: BTreeMap<(u8, &str), u32> = BTreeMap::new();
    for keep in KEEP_VERSION..=KEEP_LAYOUT {
        for _ in 0..200 {
            let header: Vec<u8> = (0..HEADER_SIZE).map(|_| rng.u8(..)).collect();
            let outcome = exercise(&random_header(&header, keep));
            *seen.entry((keep, refused_by(&outcome, keep))).or_default() += 1;
        }
    }
    eprintln!("outcomes by level kept: {seen:?}");
    let expect = [
        (KEEP_VERSION, "header_size"),
        (KEEP_FORMAT, "geometry"),
        (KEEP_GEOMETRY, "offsets"),
        (KEEP_LAYOUT, "opened"),
    ];
    for (keep, check) in expect {
        assert_eq!(
            seen.get(&(keep, check)),
            Some(&200),
            "level {keep}: not all refused by {check}: {seen:?}"
        );
    }
    // And the last check, the file length, on a valid header over a short file.
    let mut short = random_header(&[], KEEP_LAYOUT);
    short.truncate(short.len() - 4096);
    assert_eq!(refused_by(&exercise(&short), KEEP_LAYOUT), "file length");
}

/// Format 2.4's extension table: a port of an older writer (minor 3, offset 120 zero) opens
/// and its chunks have no bound; a 2.4 header whose table offset is neither the geometry's
/// nor 0 is refused, naming the field; a file cut inside the table is refused as truncated.
#[test]
fn the_extension_table_offset_is_checked_and_an_older_port_reads_without_it() {
    let valid = valid_port_bytes_cached();
    let path = common::temp_port_path("ext");
    let with = |minor: u32, ext: u64, cut: usize| {
        let mut b = valid.clone();
        b[12..16].copy_from_slice(&minor.to_ne_bytes());
        b[120..128].copy_from_slice(&ext.to_ne_bytes());
        b.truncate(b.len() - cut);
        std::fs::write(&path, &b).unwrap();
        Port::open_path(&path)
    };
    let real = u64::from_ne_bytes(valid[120..128].try_into().unwrap());
    assert!(real > 0 && real % 64 == 0, "a 2.4 writer records its table: {real}");
    // The table itself: the valid port's chunks carry the writer's rows (no bound given).
    let port = with(VERSION_MINOR, real, 0).expect("the valid port opens");
    let c = port.chunk_info(port.info().unwrap().last_frame_index).unwrap();
    assert_eq!((c.bound(), c.missing_channels), (None, 0));
    drop(port);
    // An older writer's port: no table, even cut to total_size.
    let table = valid.len() - real as usize;
    let old = with(3, 0, table).expect("a minor-3 port without the table opens");
    assert_eq!(old.chunk_info(old.info().unwrap().last_frame_index).unwrap().bound(), None);
    drop(old);
    // A minor-3 port whose word 120 holds garbage is read as minor 3 (the word was padding).
    assert!(with(3, 12345, 0).is_ok());
    match with(VERSION_MINOR, real + 64, 0) {
        Err(Error::Corrupt(m)) => assert!(m.starts_with("ext_table_offset = "), "{m}"),
        other => panic!("a wrong table offset must be refused: {:?}", other.map(drop)),
    }
    match with(VERSION_MINOR, real, 8) {
        Err(Error::Corrupt(m)) => assert!(m.contains("truncated"), "{m}"),
        other => panic!("a file cut inside the table must be refused: {:?}", other.map(drop)),
    }
    std::fs::remove_file(&path).unwrap();
}
