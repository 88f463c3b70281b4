//! The port file's life — allocated whole and refused up front on a full file system, prepared
//! before the old acquisition is touched, never opened through a link or from another
//! owner, and the states that say what is true.
//!
//! Pass: a too-large Acquire on an 8 MiB tmpfs is refused with the size needed, the space
//! free and the directory, bassd lives and the old port keeps epoch, last frame and samples;
//! a failed Acquire (missing device) after Stop changes nothing; a switch that fails after
//! it happened (sim:unplug) leaves the old window readable in the old file, and Stop clears
//! the error; a brand-new acquisition reads `starting`; a zero-filled port stops being
//! "not ready" after a bounded time; a symlink or a foreign file planted as the port is
//! refused and its target untouched; a root reader refuses a port squatted by another user;
//! a port file cut to 0 bytes under a capturing bassd ends that acquisition in error (its
//! reader gets Corrupt), bassd lives, and a new Acquire gets a higher epoch and exact data.

use std::io::{BufRead, BufReader};
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use bass_faults::figure;
use bass_test_support::{
    acquire_req, as_nobody, impersonation_missing, root_missing, setpriv, skip, wait_until, Bassd, TempDir,
    Tmpfs, NOBODY,
};
use bassport::{Error, Port, State};

/// Every frame on the port (oldest to newest), per channel, with epoch and last frame.
fn window(path: &Path) -> (u64, u64, Vec<Vec<i32>>) {
    let p = Port::open_path(path).expect("open port");
    let info = p.info().unwrap();
    let nfop = p.frames_on_port() as usize;
    let ch = info.geometry.channels as usize;
    let mut bufs = vec![vec![0i32; nfop]; ch];
    let mut nfr = (info.last_frame_index + 1).saturating_sub(nfop as u64).max(1);
    let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
    let r = p.get_audio_data(nfop, &mut nfr, &mut outs).unwrap();
    for b in &mut bufs {
        b.truncate(r.frames);
    }
    (info.epoch, info.last_frame_index, bufs)
}

fn wait_frames(b: &Bassd, frames: u64) {
    assert!(
        wait_until(Duration::from_secs(30), || b
            .client()
            .status()
            .is_ok_and(|s| s.last_frame_index >= frames)),
        "the port did not reach frame {frames}"
    );
}

fn broker_error(r: bassport::Result<bassport::control::Acquired>) -> String {
    match r {
        Err(Error::Broker(m)) => m,
        Ok(a) => panic!("Acquire accepted (epoch {})", a.epoch),
        Err(e) => panic!("not a broker refusal: {e}"),
    }
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_port_that_does_not_fit_is_refused_up_front_and_the_broker_lives() {
    if skip(root_missing().map(|why| format!("mounting a tmpfs {why}"))) {
        return;
    }
    let base = TempDir::shm("fullfs");
    let mnt = base.join("s");
    let _fs = Tmpfs::mount(&mnt, "8m");
    // The issue's repro asks for 768 kHz: above the default --max-rate, so
    // the operator widens it here; what is tested is the space check.
    let mut b = Bassd::start_stock(&mnt, "default", &["--max-rate", "768000"], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 8000, 800, 10, 2)).expect("small acquire");
    wait_frames(&b, 4000);
    // Running, then stopped: a refused Acquire changes neither.
    for stopped in [false, true] {
        if stopped {
            c.stop().unwrap();
        }
        let (epoch, lfi_before, _) = window(&b.port_path());
        let m = broker_error(c.acquire(&acquire_req("sim:pattern", 768000, 48000, 40, 2)));
        figure!(9, "item 1: port on an 8 MiB tmpfs (running={}): {m}", !stopped);
        assert!(m.contains("needs 14.7 MiB"), "size needed missing: {m}");
        assert!(m.contains("MiB is free in") && m.contains(mnt.to_str().unwrap()), "free space/dir: {m}");
        assert!(m.contains("BASS_RUNTIME_DIR"), "{m}");
        let s = c.status().expect("bassd still answers");
        assert_eq!(s.epoch, epoch, "epoch changed by a refused Acquire");
        let want = if stopped { State::Stopped } else { State::Capturing };
        assert_eq!(s.state(), Some(want));
        if stopped {
            assert_eq!(s.last_frame_index, lfi_before);
        }
    }
    let (epoch, lfi, samples) = window(&b.port_path());
    // The same refusal again through the file system's own limit: the space check races
    // nothing here, so it is the up-front check that answered; bassd is alive.
    assert!(b.is_running(), "bassd died");
    assert_eq!(window(&b.port_path()), (epoch, lfi, samples), "the stopped port changed");
    let leftovers: Vec<String> =
        bass_test_support::list_dir(&mnt).into_iter().filter(|n| n.ends_with(".tmp")).collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    b.kill(libc::SIGTERM);
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_failed_acquire_after_stop_keeps_the_stopped_port_exactly() {
    let dir = TempDir::shm("keep");
    let b = Bassd::start_stock(dir.path(), "keep", &[], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:pattern", 8000, 800, 10, 2)).unwrap();
    wait_frames(&b, 8000);
    c.stop().unwrap();
    let before = window(&b.port_path());
    let ino = std::fs::metadata(b.port_path()).unwrap().ino();
    let m = broker_error(c.acquire(&acquire_req("hw:1.0", 8000, 800, 10, 2)));
    let s = c.status().unwrap();
    figure!(
        9,
        "item 4: after stop at frame {}, acquire hw:1.0 -> {m:?}; status: epoch {} state {:?} last frame {}",
        before.1,
        s.epoch,
        s.state(),
        s.last_frame_index
    );
    assert!(m.contains("unchanged"), "the refusal should say the port is unchanged: {m}");
    assert_eq!((s.epoch, s.last_frame_index, s.state()), (before.0, before.1, Some(State::Stopped)));
    assert_eq!(window(&b.port_path()), before, "samples changed");
    assert_eq!(std::fs::metadata(b.port_path()).unwrap().ino(), ino, "the port file was replaced");
    // While running, too: the failed Acquire does not interrupt the capture.
    c.acquire(&acquire_req("sim:pattern", 8000, 800, 10, 2)).unwrap();
    let e = c.status().unwrap().epoch;
    wait_frames(&b, 800);
    broker_error(c.acquire(&acquire_req("hw:1.0", 8000, 800, 10, 2)));
    let s = c.status().unwrap();
    assert_eq!((s.epoch, s.state()), (e, Some(State::Capturing)));
    wait_frames(&b, s.last_frame_index + 800);
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_switch_that_fails_keeps_the_old_window_and_stop_clears_the_error() {
    let dir = TempDir::shm("switch");
    let b = Bassd::start_stock(dir.path(), "switch", &[], &[]);
    let mut c = b.client();
    // A new acquisition says it is starting until its first chunk (60 s away here).
    c.acquire(&acquire_req("sim:pattern", 1000, 60000, 2, 1)).unwrap();
    let s = c.status().unwrap();
    figure!(9, "item 11: state just after Acquire: {:?} (was idle)", s.state());
    assert_eq!(s.state(), Some(State::Starting));
    assert_eq!(Port::open_path(&b.port_path()).unwrap().info().unwrap().state, Some(State::Starting));
    c.acquire(&acquire_req("sim:pattern", 8000, 800, 10, 2)).unwrap();
    wait_frames(&b, 4000);
    c.stop().unwrap();
    let old = Port::open_path(&b.port_path()).unwrap();
    let before = window(&b.port_path());
    // sim:unplug opens fine and fails after half a second of data.
    c.acquire(&acquire_req("sim:unplug", 8000, 800, 10, 2)).unwrap();
    assert!(
        wait_until(Duration::from_secs(30), || c.status().is_ok_and(|s| s.state() == Some(State::Error))),
        "sim:unplug did not fail"
    );
    assert_eq!(old.info().unwrap().state, Some(State::Superseded));
    assert_eq!(old.info().unwrap().last_frame_index, before.1);
    let mut nfr = (before.1 + 1).saturating_sub(old.frames_on_port()).max(1);
    let mut buf = vec![0i32; old.frames_on_port() as usize];
    let r = old.get_audio_data(buf.len(), &mut nfr, &mut [buf.as_mut_slice()]).unwrap();
    assert_eq!(&buf[..r.frames], &before.2[0][..], "the old window is not readable in the old file");
    // Stop after the error: clears it and says so.
    let said = c.stop_report().unwrap();
    let s = c.status().unwrap();
    figure!(
        9,
        "item 11: stop after a device error -> {said:?}; state {:?}, error code {}",
        s.state(),
        s.error_code
    );
    assert!(said.contains("cleared the error state"), "{said}");
    assert_eq!((s.state(), s.error_code), (Some(State::Stopped), 0));
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_zero_filled_port_gives_up_with_never_ready_after_a_bounded_time() {
    let dir = TempDir::shm("zero");
    let path = dir.join("bass-zero.port");
    std::fs::write(&path, vec![0u8; 3 * 4096]).unwrap();
    let t0 = Instant::now();
    let mut not_ready = 0;
    let end = t0 + Duration::from_secs(30);
    let outcome = loop {
        match Port::open_path(&path) {
            Err(Error::NotReady) if Instant::now() < end => not_ready += 1,
            other => break other,
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let e = outcome.err().expect("a zero-filled port never opens");
    figure!(9, "item 9: zero-filled port: {not_ready} NotReady answers, then: {e}");
    assert!(matches!(e, Error::NeverReady { .. }), "got {e:?}");
    assert!(e.to_string().contains("never became ready"));
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_planted_symlink_or_foreign_file_is_refused_and_its_target_untouched() {
    if skip(impersonation_missing()) {
        return;
    }
    let dir = TempDir::shm("plant");
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o1777)).unwrap();
    // The victim: a root file that happens to be a valid, stopped port.
    let victims = TempDir::shm("victim");
    let victim = victims.join("victim.port");
    let g = bassport::Geometry { channels: 2, sample_rate: 8000, frames_per_chunk: 80, chunks_on_port: 4 };
    drop(
        bassport::Writer::create_at(
            &victim,
            &bassport::PortParams { geometry: g, device: "v".into(), group: None },
        )
        .unwrap(),
    );
    let victim_bytes = std::fs::read(&victim).unwrap();
    let link = dir.join("bass-default.port");
    let out = as_nobody("ln", &["-s", victim.to_str().unwrap(), link.to_str().unwrap()]);
    assert!(out.status.success(), "ln -s as nobody: {}", String::from_utf8_lossy(&out.stderr));
    let b = Bassd::start_stock(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    let m = broker_error(c.acquire(&acquire_req("sim:pattern", 8000, 80, 4, 2)));
    figure!(14, "item 1: port name planted as a symlink -> {m}");
    assert!(m.contains("symbolic link"), "{m}");
    assert_eq!(std::fs::read(&victim).unwrap(), victim_bytes, "the link's target was written");
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
    // A dangling link creates nothing where it points.
    std::fs::remove_file(&link).unwrap();
    let nowhere = victims.join("created-through-a-link");
    assert!(as_nobody("ln", &["-s", nowhere.to_str().unwrap(), link.to_str().unwrap()]).status.success());
    broker_error(c.acquire(&acquire_req("sim:pattern", 8000, 80, 4, 2)));
    assert!(!nowhere.exists(), "a file was created through a dangling link");
    // A regular file of another user in the port's place.
    std::fs::remove_file(&link).unwrap();
    assert!(as_nobody("touch", &[link.to_str().unwrap()]).status.success());
    let m = broker_error(c.acquire(&acquire_req("sim:pattern", 8000, 80, 4, 2)));
    figure!(14, "item 1: port name taken by a file of nobody -> {m}");
    assert!(m.contains("owned by uid 65534"), "{m}");
    assert_eq!(std::fs::metadata(&link).unwrap().uid(), 65534, "the foreign file was replaced");
    assert!(c.status().is_ok(), "bassd answers");
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_root_reader_refuses_a_port_squatted_by_another_user() {
    if skip(impersonation_missing()) {
        return;
    }
    let dir = TempDir::shm("squat");
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o1777)).unwrap();
    let port = dir.join("bass-default.port");
    let mut squatter = setpriv(&NOBODY, bass_faults::agent_path())
        .args(["writer", "--port", port.to_str().unwrap(), "--seconds", "60", "--pace-us", "10000"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn the squatter");
    let mut line = String::new();
    BufReader::new(squatter.stdout.take().unwrap()).read_line(&mut line).unwrap();
    assert!(line.starts_with("ready"), "squatter: {line:?}");
    std::env::set_var("BASS_RUNTIME_DIR", dir.path());
    std::env::remove_var("BASS_BROKER_UID");
    let e = Port::open("default").err().expect("a squatted port must not open");
    figure!(14, "item 2b: root reader, port of nobody -> {e}");
    assert!(matches!(e, Error::WrongOwner { .. }), "{e:?}");
    assert!(e.to_string().contains("uid 65534 (nobody)"), "{e}");
    // The operator can name the broker's uid explicitly.
    std::env::set_var("BASS_BROKER_UID", "65534");
    assert!(Port::open("default").is_ok(), "BASS_BROKER_UID=65534 accepts nobody's port");
    std::env::remove_var("BASS_BROKER_UID");
    // A runtime directory only its owner can write vouches for its owner's ports.
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    std::os::unix::fs::chown(dir.path(), Some(65534), Some(65534)).unwrap();
    assert!(Port::open("default").is_ok(), "a 0755 directory of nobody vouches for nobody's port");
    std::os::unix::fs::chown(dir.path(), Some(0), Some(0)).unwrap();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o1777)).unwrap();
    drop(squatter.stdin.take());
    squatter.kill().expect("SIGKILL the squatter");
    let st = squatter.wait().expect("wait for the squatter");
    // Killed, or ended cleanly when its stdin closed: never a crash of the writer.
    assert!(st.success() || st.signal() == Some(libc::SIGKILL), "the squatting writer ended with {st}");
    // A link at the port's name, even to a root port, is not followed by a reader.
    let real = dir.join("bass-real.port");
    let g = bassport::Geometry { channels: 1, sample_rate: 8000, frames_per_chunk: 80, chunks_on_port: 4 };
    let _w = bassport::Writer::create_at(
        &real,
        &bassport::PortParams { geometry: g, device: "r".into(), group: None },
    )
    .unwrap();
    std::fs::remove_file(&port).unwrap();
    assert!(as_nobody("ln", &["-s", real.to_str().unwrap(), port.to_str().unwrap()]).status.success());
    let e = Port::open("default").err().expect("a link at the port's name must not open");
    figure!(14, "item 2b: root reader, port name is a link -> {e}");
    assert!(e.to_string().contains("symbolic link"), "{e}");
    std::env::remove_var("BASS_RUNTIME_DIR");
}

/// Bytes of distinct bass port files (live or deleted) mapped by process `pid`.
fn mapped_port_bytes(pid: u32) -> (u64, usize) {
    let maps = std::fs::read_to_string(format!("/proc/{pid}/maps")).unwrap_or_default();
    let mut seen = std::collections::BTreeMap::new();
    for l in maps.lines().filter(|l| l.contains(".port")) {
        let f: Vec<&str> = l.split_whitespace().collect();
        let (a, b) = f[0].split_once('-').unwrap();
        let len = u64::from_str_radix(b, 16).unwrap() - u64::from_str_radix(a, 16).unwrap();
        *seen.entry((f[3].to_owned(), f[4].to_owned())).or_insert(0) += len;
    }
    (seen.values().sum(), seen.len())
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_group_member_cannot_pin_more_than_the_stated_bound_of_superseded_ports() {
    if skip(impersonation_missing()) {
        return;
    }
    let gid = bass_faults::test_group().to_string();
    let dir = TempDir::shm("pin");
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    let cap: u64 = 32 << 20;
    let b =
        Bassd::start_stock(dir.path(), "pin", &["--group", &gid, "--max-port-bytes", &cap.to_string()], &[]);
    // The issue's loop: ten Acquires of a ~28.6 MiB port, each new port opened and kept.
    let member = |rounds: &str| {
        setpriv(&["--reuid=65534", &format!("--regid={gid}"), "--clear-groups"], bass_faults::agent_path())
            .args(["pin-loop", "--socket", b.socket().to_str().unwrap(), "--name", "pin", "--rounds", rounds])
            .args(["--rate", "48000", "--nfpc", "48000", "--ncop", "78", "--channels", "2"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn the member")
    };
    let mut m = member("10");
    let mut out = BufReader::new(m.stdout.take().unwrap());
    let mut lines = Vec::new();
    loop {
        let mut l = String::new();
        assert!(out.read_line(&mut l).unwrap() > 0, "member exited early: {lines:?}");
        lines.push(l.trim_end().to_owned());
        if l.starts_with("RESULT") {
            break;
        }
    }
    let (pinned, files) = mapped_port_bytes(m.id());
    let refused: Vec<&String> = lines.iter().filter(|l| l.contains("refused")).collect();
    figure!(
        14,
        "item 4: member loop of 10 Acquire-and-keep rounds with --max-port-bytes 32 MiB: {} ({} port files, {:.1} MiB mapped; bound {} MiB); first refusal: {}",
        lines.last().unwrap(),
        files,
        pinned as f64 / f64::from(1u32 << 20),
        2 * (cap >> 20),
        refused.first().map_or("none", |s| s.as_str())
    );
    assert!(pinned <= 2 * cap, "the member pins {pinned} bytes, over the bound of {}", 2 * cap);
    assert!(!refused.is_empty(), "no Acquire was refused: {lines:?}");
    assert!(refused[0].contains("--max-port-bytes"), "{}", refused[0]);
    // The broker's own user is not limited, and a member who let go may acquire again.
    let mut c = b.client();
    c.acquire(&acquire_req("sim:silence", 48000, 48000, 78, 2)).expect("root's Acquire");
    drop(m.stdin.take());
    let st = m.wait().expect("wait for the member");
    assert!(st.success(), "the member ended with {st}");
    let mut again = member("1");
    let mut l = String::new();
    BufReader::new(again.stdout.take().unwrap()).read_line(&mut l).unwrap();
    assert!(l.contains(" ok "), "a member that released its mappings is refused: {l}");
    // The test stops reading here: the agent may meet EPIPE on its RESULT line and must end
    // quietly (status 0), not panic.
    drop(again.stdin.take());
    let st = again.wait().expect("wait for the second member");
    assert!(st.success(), "the second member ended with {st} after the test stopped reading");
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_new_port_is_wholly_allocated_not_sparse() {
    let dir = TempDir::shm("alloc");
    let path = dir.join("bass-alloc.port");
    let g =
        bassport::Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 4800, chunks_on_port: 100 };
    let w = bassport::Writer::create_at(
        &path,
        &bassport::PortParams { geometry: g, device: "a".into(), group: None },
    )
    .unwrap();
    let m = std::fs::metadata(&path).unwrap();
    let allocated = m.blocks() * 512;
    figure!(
        9,
        "item 1: a {:.1} MiB port has {:.1} MiB allocated right after creation (a sparse file had 1 page)",
        m.len() as f64 / 1048576.0,
        allocated as f64 / 1048576.0
    );
    assert!(allocated >= m.len(), "port file is sparse: {allocated} of {} bytes allocated", m.len());
    drop(w);
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_temporary_port_left_by_a_dead_writer_is_removed_by_the_next_one() {
    let dir = TempDir::shm("stale");
    // A leftover of a writer (pid 2^22 + 1 cannot exist: above pid_max's ceiling) next to
    // one of a live process (ours is never touched by another writer).
    let dead = dir.join(".bass-stale.port.4194305.0.tmp");
    std::fs::write(&dead, vec![1u8; 8192]).unwrap();
    let live = dir.join(&format!(".bass-stale.port.{}.99.tmp", std::process::id()));
    std::fs::write(&live, b"x").unwrap();
    let g = bassport::Geometry { channels: 1, sample_rate: 8000, frames_per_chunk: 80, chunks_on_port: 4 };
    let _w = bassport::Writer::create_at(
        &dir.join("bass-stale.port"),
        &bassport::PortParams { geometry: g, device: "s".into(), group: None },
    )
    .unwrap();
    assert!(!dead.exists(), "the dead writer's temporary file is still there");
    assert!(live.exists(), "a live process's temporary file was removed");
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_port_file_cut_under_the_broker_ends_the_acquisition_not_the_broker() {
    // The port file's owner (or root) cuts it to 0 bytes while bassd captures into it and a
    // reader waits on it. bassd's mapping is guarded like a reader's: its next publish fails,
    // the acquisition ends in error, and bassd stays up, says why in Status, and serves a new
    // Acquire whose port a reader reads intact. The reader of the cut port gets Corrupt.
    use basskit::testsignal::pattern_expected;
    use std::fs::OpenOptions;
    let dir = TempDir::shm("corrupt-cut-broker");
    let mut b = Bassd::start_stock(dir.path(), "cut", &[], &[]);
    let req = acquire_req("sim:pattern", 48000, 256, 64, 2);
    let first = b.client().acquire(&req).expect("acquire");
    let port = Port::open_path(&b.port_path()).unwrap();
    port.wait(4096, Duration::from_secs(10)).expect("frames before the cut");
    let (following, followed) = std::sync::mpsc::channel();
    let mut following = Some(following);
    let reader = std::thread::spawn(move || {
        let mut nfr = port.info().unwrap().last_frame_index + 1;
        loop {
            match port.wait(nfr, Duration::from_secs(10)) {
                Ok(lfi) => nfr = lfi + 1,
                other => return other,
            }
            // Woken by a publish once: the reader follows the live port.
            if let Some(tx) = following.take() {
                tx.send(()).expect("the test waits for the reader");
            }
        }
    });
    followed.recv_timeout(Duration::from_secs(10)).expect("the reader follows the port");
    OpenOptions::new().write(true).open(b.port_path()).unwrap().set_len(0).unwrap();
    let ended = reader.join().unwrap();
    assert!(matches!(ended, Err(Error::Corrupt(_))), "the reader of the cut port got {ended:?}");
    let mut status = b.client().status().expect("status");
    assert!(
        wait_until(Duration::from_secs(5), || {
            status = b.client().status().expect("status");
            status.state == bassport::State::Error as u32
        }),
        "status after the cut: {status:?}"
    );
    assert!(b.is_running(), "bassd died when its port file was cut");
    assert!(status.message.contains("shrank"), "status message: {}", status.message);
    // A new acquisition: a new port, read intact.
    let second = b.client().acquire(&req).expect("acquire after the cut");
    assert!(second.epoch > first.epoch);
    let port = Port::open_path(&b.port_path()).unwrap();
    let from = port.info().unwrap().last_frame_index + 1;
    port.wait(from + 4095, Duration::from_secs(10)).expect("frames of the new port");
    let (mut l, mut r) = (vec![0; 4096], vec![0; 4096]);
    let mut nfr = from;
    let got = port.get_audio_data(4096, &mut nfr, &mut [&mut l, &mut r]).unwrap();
    let bad = (0..got.frames)
        .filter(|&i| {
            l[i] != pattern_expected(from + i as u64, 0) || r[i] != pattern_expected(from + i as u64, 1)
        })
        .count();
    assert_eq!((got.frames, bad), (4096, 0), "the new port's frames {from}..");
    figure!(
        9,
        "port file cut to 0 under bassd: its reader got Corrupt, bassd stayed up (Status: {}), a new Acquire (epoch {} -> {}) read 4096 frames, 0 wrong",
        status.message,
        first.epoch,
        second.epoch
    );
}
