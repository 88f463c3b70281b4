//! Item 9 — permissions. Port files are 0640 with a configurable group; readers open the
//! port O_RDONLY and map it PROT_READ (checked in /proc of a reader process); a write
//! through a reader's mapping faults (SIGSEGV, in a child process); a process of another
//! uid outside the group cannot open the port, one in the group can read but not write;
//! and no reader can open a port before it is fully initialised (ports are built under a
//! temporary name and renamed into place, version written last).
//! The control socket's 0660 mode is checked in control_abuse.rs (broker).

use std::os::unix::fs::MetadataExt;
use std::os::unix::process::ExitStatusExt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use bass_faults::{figure, Agent, Fields};
use bass_test_support::TempDir;
use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, Writer};

fn geometry() -> Geometry {
    Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 32, chunks_on_port: 4 }
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn port_is_0640_with_the_configured_group_and_readers_map_it_read_only() {
    let group = bass_faults::test_group();
    let dir = TempDir::shm("perm");
    let path = dir.join("bass-perm.port");
    let plain = dir.join("bass-plain.port");
    let _w0 =
        Writer::create_at(&plain, &PortParams { geometry: geometry(), device: "p".into(), group: None })
            .unwrap();
    let m0 = std::fs::metadata(&plain).unwrap();
    // SAFETY: getegid cannot fail.
    let my_gid = unsafe { libc::getegid() };
    assert_eq!(m0.mode() & 0o777, 0o640, "mode of a port without a group");
    assert_eq!(m0.gid(), my_gid);
    let mut w = Writer::create_at(
        &path,
        &PortParams { geometry: geometry(), device: "p".into(), group: Some(group) },
    )
    .unwrap();
    w.publish(Source::Zeros, ChunkMeta::default()).unwrap();
    let m = std::fs::metadata(&path).unwrap();
    assert_eq!(m.mode() & 0o777, 0o640, "port file mode");
    assert_eq!(m.gid(), group, "port file group");
    let mut poke = Agent::spawn(&["poke", "--port", path.to_str().unwrap()]);
    let line = poke.expect_line("MAPPING");
    let f = Fields::parse(&line);
    let perms = f.s("perms").to_owned();
    let flags = u32::from_str_radix(f.s("open_flags"), 8).expect("octal flags");
    let (status, lines) = poke.finish();
    figure!(
        9,
        "port mode {:o} group {} (configured {group}); reader mapping perms {perms}, open flags {:o} (O_ACCMODE {}); write through the mapping: {:?}",
        m.mode() & 0o777,
        m.gid(),
        flags,
        flags & libc::O_ACCMODE as u32,
        status.signal().map(|s| if s == libc::SIGSEGV { "SIGSEGV".to_string() } else { s.to_string() })
    );
    assert!(
        !perms.is_empty() && perms.split(',').all(|p| p == "r--s"),
        "reader mapping must be r--s, got {perms}"
    );
    assert_eq!(flags & libc::O_ACCMODE as u32, libc::O_RDONLY as u32, "reader must open O_RDONLY");
    assert!(!lines.iter().any(|l| l == "SURVIVED"), "a write through the reader's mapping succeeded");
    assert_eq!(status.signal(), Some(libc::SIGSEGV), "the write must fault: {status}");
}

/// The permission probe on port file `path` as the user `setpriv` options name.
fn try_open_as<S: AsRef<str>>(path: &std::path::Path, setpriv: &[S]) -> Fields {
    bass_faults::try_open_as(setpriv, &["--port", path.to_str().unwrap()], &[])
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn another_uid_reads_only_through_the_group_and_never_writes() {
    let group = bass_faults::test_group();
    if bass_test_support::skip(bass_test_support::impersonation_missing()) {
        figure!(9, "SKIPPED other-uid check: needs root and setpriv");
        return;
    }
    let dir = TempDir::shm("perm-uid");
    std::fs::set_permissions(dir.path(), std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let path = dir.join("bass-uid.port");
    let mut w = Writer::create_at(
        &path,
        &PortParams { geometry: geometry(), device: "p".into(), group: Some(group) },
    )
    .unwrap();
    w.publish(Source::Zeros, ChunkMeta::default()).unwrap();
    let outsider = try_open_as(&path, &bass_test_support::NOBODY);
    let member = try_open_as(&path, &bass_test_support::nobody_in_group(group));
    figure!(
        9,
        "uid 65534 outside the group: read={} write={}; in group {group}: read={} write={}",
        outsider.s("read"),
        outsider.s("write"),
        member.s("read"),
        member.s("write")
    );
    // Refused by the system (EACCES); the library explains the refusal (the group to join)
    // in an error of kind PermissionDenied.
    assert!(
        [format!("io:{}", libc::EACCES), "io:PermissionDenied".to_owned()]
            .contains(&outsider.s("read").to_owned()),
        "an outsider must not open the port: {}",
        outsider.s("read")
    );
    assert_eq!(outsider.s("write"), format!("io:{}", libc::EACCES));
    assert!(member.s("read").starts_with("ok"), "a group member must open the port: {member:?}");
    assert_eq!(
        member.s("write"),
        format!("io:{}", libc::EACCES),
        "a group member must not open it for writing"
    );
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn no_reader_ever_opens_a_half_initialised_port() {
    let dir = TempDir::shm("perm-init");
    let path = dir.join("bass-init.port");
    let done = Arc::new(AtomicBool::new(false));
    let opens = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let recreations = 300u64;
    let reader = {
        let (path, done, opens) = (path.clone(), done.clone(), opens.clone());
        std::thread::spawn(move || {
            let (mut ok, mut not_found, mut max_epoch) = (0u64, 0u64, 0u64);
            while !done.load(Ordering::Relaxed) {
                match Port::open_path(&path) {
                    Ok(p) => {
                        let info = p.info().expect("info of an opened port");
                        assert_eq!(info.device, "init-race", "device written before the version");
                        assert_eq!(info.geometry, geometry());
                        assert!(p.epoch() >= 1 && p.epoch() <= recreations);
                        max_epoch = max_epoch.max(p.epoch());
                        ok += 1;
                        opens.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(Error::NotFound { .. }) => not_found += 1,
                    Err(e) => panic!("a reader saw a half-initialised port: {e:?}"),
                }
            }
            (ok, not_found, max_epoch)
        })
    };
    for _ in 0..recreations {
        let mut w = Writer::create_at(
            &path,
            &PortParams { geometry: geometry(), device: "init-race".into(), group: None },
        )
        .unwrap();
        w.publish(Source::Zeros, ChunkMeta::default()).unwrap();
    }
    // However the threads were scheduled, let the reader open the final port at least once.
    bass_test_support::wait_until(std::time::Duration::from_secs(10), || opens.load(Ordering::Relaxed) > 0);
    done.store(true, Ordering::Relaxed);
    let (ok, not_found, max_epoch) = reader.join().expect("reader thread");
    let leftovers: Vec<String> = dir.entries().into_iter().filter(|e| e != "bass-init.port").collect();
    figure!(9, "init race: {recreations} port creations (epochs 1..{recreations}) against a reader opening in a loop: {ok} opens, all fully initialised (max epoch seen {max_epoch}), {not_found} NotFound before the first, 0 NotReady/Corrupt; temporary files left: {}", leftovers.len());
    assert!(ok > 0, "the reader never opened the port");
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
}
