//! What the corrupted-port cases of corrupt_ports share: the header's fields (from its one definition),
//! a valid port to start from, and the exercise of every library call on a damaged file with
//! the tally of what each returned.

use std::mem::{offset_of, size_of};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::time::Duration;

use bass_test_support::TempDir;
use basskit::testsignal::fill_pattern_interleaved;
use bassport::format::Header;
use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, Writer};

pub const NFPC: u32 = 16;
pub const NCOP: u32 = 4;

/// Width in bytes of the header field `f` points at.
pub fn width<T>(_: fn(&Header) -> &T) -> usize {
    size_of::<T>()
}

/// Every header field as (name, offset, width in bytes), from the one definition of the
/// layout (`bassport::format::Header`), not typed in: a field added there is fuzzed here.
macro_rules! fields {
    ($($f:ident),* $(,)?) => { [$((stringify!($f), offset_of!(Header, $f), width(|h| &h.$f))),*] };
}

pub fn fields() -> [(&'static str, usize, usize); 31] {
    fields![
        magic,
        version_major,
        version_minor,
        header_size,
        channels,
        sample_format,
        sample_rate,
        frames_per_chunk,
        chunks_on_port,
        chunk_table_offset,
        samples_offset,
        total_size,
        epoch,
        writer_pid,
        state,
        writer_start_time,
        created_realtime_ns,
        error_code,
        futex,
        restart_grace_ms,
        writer_pid_ns,
        ext_table_offset,
        last_frame_index,
        write_intent,
        heartbeat_mono_ns,
        xruns,
        gap_frames,
        chunks_published,
        rate_estimate_mhz,
        started_mono_ns,
        lost_upstream_frames,
    ]
}

pub fn valid_port(dir: &TempDir) -> Vec<u8> {
    let path = dir.join("bass-src.port");
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: NFPC, chunks_on_port: NCOP };
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "corrupt".into(), group: None }).unwrap();
    let mut chunk = vec![0; (NFPC * 2) as usize];
    for _ in 0..6 {
        fill_pattern_interleaved(&mut chunk, 2, w.last_frame_index() + 1);
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
    }
    let bytes = std::fs::read(&path).unwrap();
    w.remove().unwrap();
    bytes
}

/// Named errors a bad port may give on open.
pub fn open_error_ok(e: &Error) -> bool {
    matches!(e, Error::NotReady | Error::BadMagic { .. } | Error::Incompatible { .. } | Error::Corrupt(_))
}

/// Outcomes a read call on an opened (possibly hostile) port may give.
pub fn call_error_ok(e: &Error) -> bool {
    matches!(
        e,
        Error::Corrupt(_)
            | Error::Timeout { .. }
            | Error::Stopped { .. }
            | Error::Device { .. }
            | Error::Restarted
            | Error::WriterGone { .. }
            | Error::FrameLost { .. }
            | Error::FrameNotYet { .. }
    )
}

#[derive(Default, Debug)]
pub struct Tally {
    pub cases: u64,
    pub opened: u64,
    pub refused: std::collections::BTreeMap<&'static str, u64>,
    pub calls: u64,
    pub call_errors: u64,
}

pub fn kind(e: &Error) -> &'static str {
    match e {
        Error::NotReady => "NotReady",
        Error::BadMagic { .. } => "BadMagic",
        Error::Incompatible { .. } => "Incompatible",
        Error::Corrupt(_) => "Corrupt",
        Error::NotFound { .. } => "NotFound",
        Error::Io { .. } => "Io",
        _ => "other",
    }
}

/// Opens `path` and runs every read path; returns the open error if refused.
/// Panics (with the case name) on a disallowed outcome.
pub fn exercise_path(path: &Path, case: &str, t: &mut Tally) -> Option<Error> {
    t.cases += 1;
    let port = match catch_unwind(|| Port::open_path(path)) {
        Err(_) => panic!("{case}: open panicked"),
        Ok(Err(e)) => {
            assert!(open_error_ok(&e), "{case}: open gave {e:?}, not a named port error");
            assert!(!e.to_string().is_empty());
            *t.refused.entry(kind(&e)).or_default() += 1;
            return Some(e);
        }
        Ok(Ok(p)) => p,
    };
    t.opened += 1;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; 512]; channels];
    let mut check = |what: &str, r: Result<(), Error>| {
        t.calls += 1;
        if let Err(e) = r {
            t.call_errors += 1;
            assert!(call_error_ok(&e), "{case}: {what} gave {e:?}");
        }
    };
    let run = catch_unwind(AssertUnwindSafe(|| {
        for start in [0u64, 1, 5, 50, 95, 96, 97, 1 << 40, u64::MAX / 2, u64::MAX - 1, u64::MAX] {
            for n in [0usize, 1, 64, 512] {
                let mut nfr = start;
                let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
                check("get_audio_data", port.get_audio_data(n, &mut nfr, &mut outs).map(drop));
                let mut nfr = start;
                check(
                    "view",
                    port.view(n, &mut nfr).map(|v| {
                        // Read the view in place, as a zero-copy client would.
                        for c in 0..channels {
                            let ring = port.channel_ring(c).unwrap();
                            for (s, l) in v.segments {
                                for slot in s..s + l {
                                    std::hint::black_box(ring.load(slot));
                                }
                            }
                        }
                        port.view_overwritten(&v);
                    }),
                );
            }
            check("chunk_info", port.chunk_info(start).map(drop));
            check("wait", port.wait(start, Duration::ZERO).map(drop));
        }
        check("info", port.info().map(drop));
    }));
    assert!(run.is_ok(), "{case}: a read call panicked");
    None
}

pub fn exercise(dir: &TempDir, bytes: &[u8], case: &str, t: &mut Tally) -> Option<Error> {
    let path = dir.join("bass-case.port");
    std::fs::write(&path, bytes).unwrap();
    let r = exercise_path(&path, case, t);
    std::fs::remove_file(&path).expect("remove the case's port file");
    r
}

pub fn put(bytes: &mut [u8], off: usize, width: usize, v: u64) {
    bytes[off..off + width].copy_from_slice(&v.to_le_bytes()[..width]);
}
