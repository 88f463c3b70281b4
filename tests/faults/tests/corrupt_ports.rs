//! Item 5 — corrupted port files: random bytes; truncation at every header boundary; each
//! header field set to extreme values one at a time; the magic or major version of another
//! format; the file shrunk while a reader has it mapped (sequentially, and concurrently
//! with a reader process hammering every library call).
//!
//! Pass: never a panic, never a crash (SIGBUS/SIGSEGV would kill the test process or the
//! victim process), and every failure is one of the named errors that describe a bad port
//! (`NotReady`, `BadMagic`, `Incompatible`, `Corrupt`) or a normal read outcome. A port
//! that opens must answer every read call without touching memory outside its mapping.
//! run.sh runs this file twice: in release and in a debug build (overflow checks on).

use std::fs::OpenOptions;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::{Duration, Instant};

use bass_faults::{figure, Agent, Rng};
use bass_test_support::TempDir;
use basskit::testsignal::fill_pattern_interleaved;
use bassport::format::HEADER_SIZE;
use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, Writer};

mod corrupt;

use corrupt::*;

/// The list above names every numeric field of `Header` (the text fields `message` and
/// `device` are left out): a field added to format.rs and not here fails this test.
#[test]
fn the_fuzzed_fields_are_every_numeric_field_of_the_header() {
    let src = include_str!("../../../port/src/format.rs");
    let body = src.split("pub struct Header {").nth(1).and_then(|b| b.split("\n}").next()).expect("Header");
    let declared: Vec<&str> = body
        .lines()
        .filter_map(|l| l.trim().strip_prefix("pub ")?.split(':').next())
        .filter(|name| !matches!(*name, "message" | "device"))
        .collect();
    let fuzzed: Vec<&str> = fields().iter().map(|f| f.0).collect();
    assert_eq!(fuzzed, declared, "corrupt_ports's fields against format.rs's Header");
}
#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn random_bytes_never_crash_and_give_named_errors() {
    let dir = TempDir::shm("corrupt-random");
    let good = valid_port(&dir);
    let seed = bass_faults::seed();
    let mut rng = Rng::with_seed(seed);
    let mut t = Tally::default();
    for i in 0..400 {
        // Whole files of random bytes and random length.
        let len = rng.u64(..3 * good.len() as u64) as usize;
        let bytes: Vec<u8> = (0..len).map(|_| rng.u8(..)).collect();
        exercise(&dir, &bytes, &format!("random file {i} (seed {seed})"), &mut t);
        // A valid magic and version followed by random bytes, so validation goes deeper.
        let mut bytes = good.clone();
        for b in bytes[12..HEADER_SIZE].iter_mut() {
            *b = rng.u8(..);
        }
        exercise(&dir, &bytes, &format!("random header {i} (seed {seed})"), &mut t);
        // The valid port with a few random bytes changed anywhere in the header.
        let mut bytes = good.clone();
        for _ in 0..1 + rng.u64(..8) {
            let off = rng.u64(..640) as usize;
            bytes[off] = rng.u8(..);
        }
        exercise(&dir, &bytes, &format!("mutated header {i} (seed {seed})"), &mut t);
    }
    figure!(5, "random: {} cases (seed {seed}): {} opened (every read call answered, {} of {} calls refused with a named error), refused on open {:?}", t.cases, t.opened, t.call_errors, t.calls, t.refused);
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn truncation_at_every_boundary_is_corrupt() {
    let dir = TempDir::shm("corrupt-trunc");
    let good = valid_port(&dir);
    let total = good.len();
    let samples = 8192usize; // 4096 + 32 * 4, rounded up to 4096
    let mut cuts: Vec<usize> = (0..=64).collect();
    for (_, off, width) in fields() {
        cuts.extend([off, off + 1, off + width - 1, off + width]);
    }
    cuts.extend([
        255,
        256,
        511,
        512,
        639,
        640,
        4095,
        4096,
        4097,
        4096 + 32,
        4096 + 32 * NCOP as usize,
        samples - 1,
        samples,
    ]);
    let nfop = (NFPC * NCOP) as usize;
    for c in 0..=2 {
        let ring = samples + c * nfop * 4;
        cuts.extend([ring.saturating_sub(1), ring, ring + 1, ring + 4]);
    }
    cuts.extend([total - 4, total - 1]);
    cuts.retain(|&c| c < total);
    cuts.sort();
    cuts.dedup();
    let mut t = Tally::default();
    for &cut in &cuts {
        let e = exercise(&dir, &good[..cut], &format!("truncated at {cut}"), &mut t);
        match e {
            Some(Error::Corrupt(_)) => {}
            // A cut inside the first 12 bytes leaves a magic or version that reads as 0 / not ours.
            Some(Error::BadMagic { .. } | Error::NotReady) if cut < 12 => {}
            other => panic!("truncated at {cut}: expected Corrupt, got {other:?}"),
        }
    }
    figure!(
        5,
        "truncation: {} cut points from 0 to {} bytes: all refused on open {:?}",
        cuts.len(),
        total - 1,
        t.refused
    );
    assert_eq!(t.opened, 0);
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn every_header_field_at_extreme_values_is_handled() {
    let dir = TempDir::shm("corrupt-fields");
    let good = valid_port(&dir);
    let mut t = Tally::default();
    let mut summary = Vec::new();
    for (name, off, width) in fields() {
        let max = if width == 8 { u64::MAX } else { u64::from(u32::MAX) };
        let high = 1u64 << (width * 8 - 1);
        let mut values = vec![0, 1, 2, 3, 4, 64, 65, max, max - 1, high, high - 1];
        if width == 8 {
            values.extend([1 << 62, (1 << 62) + 1, 1 << 32]);
        }
        let mut outcomes = std::collections::BTreeSet::new();
        for v in values {
            let mut bytes = good.clone();
            put(&mut bytes, off, width, v);
            let e = exercise(&dir, &bytes, &format!("{name} = {v:#x}"), &mut t);
            outcomes.insert(e.as_ref().map_or("opens", kind));
        }
        summary.push(format!("{name}:{}", outcomes.into_iter().collect::<Vec<_>>().join("/")));
    }
    figure!(5, "extreme field values: {} cases, {} opened and answered {} read calls ({} named errors); per field: {}", t.cases, t.opened, t.calls, t.call_errors, summary.join(" "));
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_hostile_write_intent_never_delivers_frames_it_cannot_vouch_for() {
    // write_intent beyond the format's frame limit (e.g. u64::MAX) is a corrupt header:
    // the reader must not overflow (a panic in a debug build) nor trust any frame.
    let dir = TempDir::shm("corrupt-intent");
    let good = valid_port(&dir);
    for intent in [u64::MAX, u64::MAX - 1, (1 << 62) + 1] {
        let mut bytes = good.clone();
        put(&mut bytes, 136, 8, intent);
        let path = dir.join("bass-intent.port");
        std::fs::write(&path, &bytes).unwrap();
        let port = Port::open_path(&path).unwrap();
        let (mut l, mut r) = (vec![0; 64], vec![0; 64]);
        let mut nfr = 50;
        let got = catch_unwind(AssertUnwindSafe(|| port.get_audio_data(64, &mut nfr, &mut [&mut l, &mut r])));
        match got {
            Err(_) => panic!("write_intent = {intent:#x}: get_audio_data panicked"),
            Ok(Ok(read)) => assert_eq!(
                read.frames, 0,
                "write_intent = {intent:#x}: {read:?} delivered frames the intent cannot vouch for"
            ),
            Ok(Err(e)) => assert!(matches!(e, Error::Corrupt(_)), "write_intent = {intent:#x}: {e:?}"),
        }
        let mut nfr = 50;
        let got = catch_unwind(AssertUnwindSafe(|| {
            port.view(64, &mut nfr).map(|v| (v, port.view_overwritten(&v)))
        }));
        match got {
            Err(_) => panic!("write_intent = {intent:#x}: view/view_overwritten panicked"),
            Ok(Ok((v, over))) => {
                assert_eq!(over, v.frames as u64, "write_intent = {intent:#x}: view says intact")
            }
            Ok(Err(e)) => assert!(matches!(e, Error::Corrupt(_)), "{e:?}"),
        }
        let got = catch_unwind(AssertUnwindSafe(|| port.chunk_info(90)));
        assert!(got.is_ok(), "write_intent = {intent:#x}: chunk_info panicked");
    }
    figure!(5, "hostile write_intent (2^64-1, 2^64-2, 2^62+1): no panic, no frame delivered as intact");
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn foreign_magic_and_major_versions_are_refused_by_name() {
    let dir = TempDir::shm("corrupt-magic");
    let good = valid_port(&dir);
    let mut t = Tally::default();
    let magics: [(&str, [u8; 8]); 5] = [
        ("ELF", *b"\x7fELF\x02\x01\x01\x00"),
        ("byte-swapped BASSPORT", *b"TROPSSAB"),
        ("BASSPORX", *b"BASSPORX"),
        ("PNG", *b"\x89PNG\r\n\x1a\n"),
        ("all ones", [0xff; 8]),
    ];
    for (name, m) in magics {
        let mut bytes = good.clone();
        bytes[..8].copy_from_slice(&m);
        let e = exercise(&dir, &bytes, name, &mut t);
        assert!(matches!(e, Some(Error::BadMagic { .. })), "{name}: {e:?}");
    }
    // Major 1 is the previous format (32-bit sample accesses): refused like any other.
    for major in [1u32, 3, 0x100, u32::MAX] {
        let mut bytes = good.clone();
        put(&mut bytes, 8, 4, u64::from(major));
        let e = exercise(&dir, &bytes, &format!("major {major}"), &mut t);
        assert!(
            matches!(e, Some(Error::Incompatible { found, expected: 2 }) if found == major),
            "major {major}: {e:?}"
        );
    }
    let mut bytes = good.clone();
    put(&mut bytes, 8, 4, 0);
    assert!(matches!(exercise(&dir, &bytes, "major 0", &mut t), Some(Error::NotReady)));
    figure!(
        5,
        "foreign formats: 5 magics -> BadMagic, majors 1/3/256/2^32-1 -> Incompatible, major 0 -> NotReady"
    );
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_port_shrunk_under_a_reader_gives_corrupt_not_sigbus() {
    // A reader of a port file is guarded against SIGBUS (bassport::sigbus): a call that
    // touches a page the shrink removed is refused with Corrupt (and the handle stays
    // refused, its mapping replaced by zero pages); a call that touches only pages still in
    // the file reads them. For 7 sizes from total - 1 down to 0, a fresh reader of a full
    // window makes the five calls and a whole-window read.
    let dir = TempDir::shm("corrupt-shrink");
    let path = dir.join("bass-shrink.port");
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: NFPC, chunks_on_port: NCOP };
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "shrink".into(), group: None }).unwrap();
    let mut chunk = vec![0; 2 * NFPC as usize];
    for _ in 0..=NCOP {
        fill_pattern_interleaved(&mut chunk, 2, w.last_frame_index() + 1);
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
    }
    let layout = *w.layout();
    let total = layout.mapped_size; // the file's size: the rings and the extension table
    let nfop = layout.frames_on_port as usize;
    let samples_end = layout.samples_offset + 2 * layout.frames_on_port * 4;
    let lfi = w.last_frame_index();
    let pristine = std::fs::read(&path).unwrap();
    let file = OpenOptions::new().write(true).open(&path).unwrap();
    let mut t = Tally::default();
    let (mut corrupt, mut whole_refused) = (0, 0);
    for size in [total - 1, total - 4096, 8192, 4096 + 1, 4096, 100, 0] {
        let port = Port::open_path(&path).unwrap();
        file.set_len(size).unwrap();
        let (mut l, mut r) = (vec![0; nfop], vec![0; nfop]);
        let mut nfr = 1;
        let results = [
            ("get_audio_data", port.get_audio_data(64, &mut nfr, &mut [&mut l, &mut r]).map(|g| g.frames)),
            ("view", port.view(64, &mut nfr).map(|v| v.frames)),
            ("chunk_info", port.chunk_info(lfi).map(|_| 0)),
            ("info", port.info().map(|_| 0)),
            ("wait", port.wait(1, Duration::ZERO).map(|_| 0)),
        ];
        for (what, r) in results {
            t.calls += 1;
            match r {
                // With the whole header page gone nothing can be read; with only part of it
                // (the rest zeroed by the shrink: frame index 0) nothing is delivered.
                Ok(frames) => assert!(
                    size >= 4096 || (size > 0 && frames == 0),
                    "file shrunk to {size}: {what} delivered {frames} frames"
                ),
                Err(Error::Corrupt(_)) => corrupt += 1,
                // Part of the header page kept, the rest zeroed: the calls answer from a
                // header that says frame 0, writer pid 0 (a named error, nothing delivered).
                Err(_) if size > 0 && size < 4096 => {}
                Err(e) => panic!("file shrunk to {size}: {what} gave {e:?}, expected Ok or Corrupt"),
            }
        }
        // The whole window touches every sample page: refused exactly when one is gone (a
        // page stays while it starts before the new end of the file).
        let mut nfr = 0;
        let whole = port.get_audio_data(nfop, &mut nfr, &mut [&mut l, &mut r]);
        let pages_gone = size.div_ceil(4096) * 4096 < samples_end;
        match whole {
            Ok(got) if size < 4096 => {
                assert_eq!(got.frames, 0, "size {size}: a zeroed header delivers nothing")
            }
            Ok(got) => {
                assert!(!pages_gone, "file shrunk to {size}: the whole window read Ok");
                assert_eq!(got.frames, nfop);
                // Only what the shrink zeroed in the last page it kept may differ.
                let bad = bass_faults::count_corrupted(lfi + 1 - nfop as u64, nfop, &[l.clone(), r.clone()]);
                let zeroed = samples_end.saturating_sub(size).div_ceil(4);
                assert!(bad <= zeroed, "size {size}: {bad} samples wrong, only {zeroed} were cut");
            }
            Err(Error::Corrupt(m)) => {
                assert!(
                    pages_gone || size < 4096,
                    "file shrunk to {size}: refused although every page is there: {m}"
                );
                whole_refused += 1;
            }
            Err(e) => panic!("file shrunk to {size}: whole window gave {e:?}"),
        }
        file.set_len(total).unwrap();
        std::os::unix::fs::FileExt::write_all_at(&file, &pristine, 0).unwrap();
        if pages_gone && size >= 4096 {
            // The guard replaced this handle's mapping: refused for good, even now that the
            // size is back; a new handle reads again.
            let mut nfr = 1;
            assert!(matches!(
                port.get_audio_data(64, &mut nfr, &mut [&mut l, &mut r]),
                Err(Error::Corrupt(_))
            ));
        }
        let again = Port::open_path(&path).unwrap();
        let mut nfr = 1;
        assert!(
            again.get_audio_data(64, &mut nfr, &mut [&mut l, &mut r]).is_ok(),
            "a new handle reads again"
        );
    }
    figure!(
        5,
        "shrunk while mapped (7 sizes from total-1 down to 0): {} calls, {corrupt} BASS_ERR_CORRUPT (every call that touched a removed page), the rest answered from pages still there (with part of the header page kept: a named error or Ok with no frames); whole-window read refused at {whole_refused} of 7 sizes; no SIGBUS",
        t.calls
    );
    std::mem::forget(w); // its mapping lost pages too: no Drop writing into them
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_port_shrinking_while_a_reader_process_hammers_it_kills_no_reader() {
    // A reader process calls every size-dependent function in a loop while the file is cut
    // to one page and restored. The per-call size check cannot catch a shrink that lands
    // between it and the access (before the SIGBUS guard, 5 of 5 reader processes died of
    // SIGBUS within 1-12 cycles); the guard (bassport::sigbus) turns that SIGBUS into a
    // Corrupt error of the call. No reader may die, and every call must end Ok or Corrupt.
    let dir = TempDir::shm("corrupt-shrink-live");
    let path = dir.join("bass-shrink-live.port");
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: 1024, chunks_on_port: 64 };
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "shrink".into(), group: None }).unwrap();
    for _ in 0..64 {
        w.publish(Source::Zeros, ChunkMeta::default()).unwrap();
    }
    let total = w.layout().mapped_size;
    let file = OpenOptions::new().write(true).open(&path).unwrap();
    let (mut runs, mut sigbus, mut cycles_to_sigbus) = (0, 0, Vec::new());
    let (mut calls, mut corrupt, mut guarded) = (0u64, 0u64, 0);
    let started = Instant::now();
    for _ in 0..5 {
        let mut v = Agent::spawn(&["shrink-victim", "--port", path.to_str().unwrap()]);
        v.expect_line("ready");
        let mut cycles = 0;
        while cycles < 2000 && v.child.try_wait().unwrap().is_none() {
            file.set_len(4096).unwrap();
            std::thread::sleep(Duration::from_micros(50));
            file.set_len(total).unwrap();
            std::thread::sleep(Duration::from_micros(50));
            cycles += 1;
        }
        v.close_stdin();
        let (status, lines) = v.finish();
        use std::os::unix::process::ExitStatusExt;
        runs += 1;
        match status.signal() {
            Some(libc::SIGBUS) => {
                sigbus += 1;
                cycles_to_sigbus.push(cycles);
            }
            None => assert!(status.success(), "reader process failed: {status}: {lines:?}"),
            Some(sig) => panic!("reader process killed by signal {sig}"),
        }
        // RESULT calls=N ok=N corrupt=N other=N
        let result = lines.iter().find_map(|l| l.strip_prefix("RESULT ")).expect("a RESULT line");
        let field = |k: &str| -> u64 {
            result
                .split_whitespace()
                .find_map(|kv| kv.strip_prefix(k)?.strip_prefix('=')?.parse().ok())
                .unwrap()
        };
        assert_eq!(field("other"), 0, "calls ended with errors other than Corrupt: {result}");
        assert_eq!(field("ok") + field("corrupt"), field("calls"), "{result}");
        calls += field("calls");
        corrupt += field("corrupt");
        // A reader whose guard caught a SIGBUS gets Corrupt from every later call.
        guarded += usize::from(lines.iter().any(|l| l.starts_with("GUARDED")));
    }
    figure!(
        5,
        "shrink race: {runs} reader processes x up to 2000 shrink/restore cycles ({:.2} s): {sigbus} died of SIGBUS (after {cycles_to_sigbus:?} cycles); {calls} calls, {corrupt} Corrupt, the rest Ok; {guarded} of the readers had a SIGBUS caught by the guard",
        started.elapsed().as_secs_f64()
    );
    assert_eq!(sigbus, 0, "a SIGBUS reached a reader process while the port shrank");
    drop(w);
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_sealed_memfd_port_cannot_shrink_under_a_reader_process() {
    // The memfd backing (bassd --port-backing memfd) removes the limitation above: the port
    // is sealed F_SEAL_SHRINK | F_SEAL_GROW | F_SEAL_FUTURE_WRITE | F_SEAL_SEAL, so even its
    // owner, through a writable descriptor, cannot change its size or punch holes in it.
    // A reader process holding it (a descriptor handed over as bassd does, here inherited)
    // hammers every size-dependent call while the test tries to shrink, grow and punch it.
    use rustix::fs::{FallocateFlags, Mode, OFlags};
    use rustix::io::Errno;
    use std::os::fd::{AsFd, AsRawFd};
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: 1024, chunks_on_port: 64 };
    let params = PortParams { geometry, device: "shrink-memfd".into(), group: None };
    // A name of its own: a memfd port only looks at the runtime directory for a left-over
    // port file of that name, and puts nothing there.
    let name = format!("shrink-memfd-{}", std::process::id());
    let mut w = Writer::prepare_memfd(&name, &params, None).unwrap().commit().unwrap();
    assert!(!w.path().exists(), "a memfd port has no file at {}", w.path().display());
    let mut chunk = vec![0; 2048];
    for _ in 0..64 {
        fill_pattern_interleaved(&mut chunk, 2, w.last_frame_index() + 1);
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
    }
    let total = w.layout().mapped_size;
    // The strongest handle there is: the writer's memfd reopened read-write by its owner.
    let reader_fd = w.reader_fd().unwrap().expect("a memfd port hands out descriptors");
    let rw = rustix::fs::open(
        format!("/proc/self/fd/{}", reader_fd.as_raw_fd()).as_str(),
        OFlags::RDWR | OFlags::CLOEXEC,
        Mode::empty(),
    )
    .unwrap();
    let (mut runs, mut refused, mut calls) = (0, 0u64, 0u64);
    for _ in 0..3 {
        let fd = w.reader_fd().unwrap().unwrap();
        rustix::io::fcntl_setfd(&fd, rustix::io::FdFlags::empty()).unwrap(); // inherited by the agent
        let fd_arg = fd.as_raw_fd().to_string();
        let mut v = Agent::spawn(&["shrink-victim", "--fd", &fd_arg]);
        drop(fd);
        v.expect_line("ready");
        for _ in 0..2000 {
            assert_eq!(rustix::fs::ftruncate(&rw, 4096), Err(Errno::PERM), "shrink must be refused");
            assert_eq!(rustix::fs::ftruncate(&rw, total + 4096), Err(Errno::PERM), "grow must be refused");
            let punch = FallocateFlags::PUNCH_HOLE | FallocateFlags::KEEP_SIZE;
            assert_eq!(rustix::fs::fallocate(&rw, punch, 0, total), Err(Errno::PERM), "hole punch refused");
            refused += 3;
            std::thread::sleep(Duration::from_micros(100));
        }
        v.close_stdin();
        let (status, lines) = v.finish();
        assert!(status.success(), "reader process failed: {status}: {lines:?}");
        let result = lines.iter().find(|l| l.starts_with("RESULT")).expect("RESULT line");
        let f = bass_faults::Fields::parse(result);
        assert!(f.u("calls") > 0 && f.u("ok") == f.u("calls"), "every call must succeed: {result}");
        calls += f.u("calls");
        runs += 1;
    }
    // Every sample of the window is still the pattern.
    let port = Port::from_fd(reader_fd, "shrink-memfd").unwrap();
    assert!(port.size_sealed());
    assert_eq!(rustix::fs::fstat(port.file().as_fd()).unwrap().st_size as u64, total);
    let nfop = port.frames_on_port() as usize;
    let mut bufs = vec![vec![0i32; nfop]; 2];
    let mut nfr = 1;
    let r = {
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        port.get_audio_data(nfop, &mut nfr, &mut outs).unwrap()
    };
    assert_eq!((r.frames, r.loss), (nfop, 0));
    assert_eq!(bass_faults::count_corrupted(1, nfop, &bufs), 0, "every sample must be the pattern");
    figure!(
        5,
        "sealed memfd port: {runs} reader processes, {refused} shrink/grow/punch attempts all EPERM, \
         {calls} library calls all ok, 0 SIGBUS, {nfop} frames x 2 channels exact"
    );
    drop(w);
}
