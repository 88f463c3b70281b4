//! `bassd --port-backing memfd`: the port is a sealed memfd that the broker
//! hands to readers over the control socket (`open-port`, SCM_RIGHTS).
//!
//! Pass: no port file appears in the runtime directory; a reader process that opens the
//! port by name (unchanged `Port::open`) gets it through the broker, sealed, and reads the
//! `sim:pattern` signal with 0 corrupted samples and exact accounting; a uid outside
//! `--group` gets no descriptor (and no port), a member does; a Stop/Acquire cycle makes a
//! waiting reader of the old port see `Restarted`, as with files, and the next `open-port`
//! hands out the new epoch; the old memfd is counted as pinned while a reader maps it, and
//! released once it is unmapped (the same ledger as for files).

use std::time::{Duration, Instant};

use bass_faults::{figure, Agent, Fields};
use bass_test_support::{
    acquire_req, bin_path, impersonation_missing, nobody_in_group, skip, wait_until, Bassd, TempDir, NOBODY,
};
use basskit::testsignal::pattern_expected;
use bassport::control::OpenedPort;
use bassport::{Error, Port, State};

const PATIENCE: Duration = Duration::from_secs(20);

fn open_by_broker(b: &Bassd) -> (u64, Port) {
    match b.client().open_port().expect("open-port") {
        OpenedPort::Fd { epoch, fd } => (epoch, Port::from_fd(fd, &b.name).expect("map the port")),
        OpenedPort::File(p) => panic!("a memfd broker answered with a file: {}", p.display()),
    }
}

fn wait_for_frame(port: &Port, frame: u64) {
    port.wait(frame, PATIENCE).unwrap_or_else(|e| panic!("waiting for frame {frame}: {e}"));
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_reader_opened_by_name_reads_the_memfd_port_through_the_broker() {
    let dir = TempDir::shm("memfd-name");
    let group = bass_faults::test_group();
    let b = Bassd::start_stock(
        dir.path(),
        "mfd",
        &["--port-backing", "memfd", "--group", &group.to_string()],
        &[],
    );
    let got = b.client().acquire(&acquire_req("sim:pattern", 48000, 256, 64, 2)).expect("acquire");
    assert!(!b.port_path().exists(), "a memfd broker puts no port file at {}", b.port_path().display());
    let env = [("BASS_RUNTIME_DIR", dir.path().to_str().unwrap())];
    let mut reader = Agent::spawn_env(&["reader", "--name", "mfd", "--mode", "wait", "--n", "256"], &env);
    reader.expect_line("ready");
    let (_, port) = open_by_broker(&b);
    assert!(port.size_sealed(), "the handed-over port is sealed");
    assert_eq!(port.epoch(), got.epoch);
    wait_for_frame(&port, 48000);
    b.client().stop().expect("stop");
    let (status, lines) = reader.finish();
    assert!(status.success(), "reader: {status} {lines:?}");
    let f = Fields::parse(lines.iter().find(|l| l.starts_with("RESULT")).expect("RESULT"));
    let lfi = port.info().unwrap().last_frame_index;
    assert_eq!(f.u("corrupted"), 0, "{lines:?}");
    assert_eq!(f.u("delivered") + f.u("lost"), lfi, "every frame accounted for: {lines:?}");
    assert_eq!(f.u("requested"), lfi);
    assert!(f.u("delivered") > 0, "{lines:?}");

    // Other users: the socket is 0660 with --group; a member gets the sealed port, an
    // outsider neither a descriptor nor a port.
    let as_uid = |setpriv: &[&str]| -> Fields {
        bass_faults::try_open_as(setpriv, &["--name", "mfd"], &[("BASS_RUNTIME_DIR", dir.path())])
    };
    let (mut member_read, mut outsider_read) = ("skipped (not root)".to_owned(), "skipped".to_owned());
    if !skip(impersonation_missing()) {
        let member = nobody_in_group(group);
        let member = as_uid(&member.iter().map(String::as_str).collect::<Vec<_>>());
        let outsider = as_uid(&NOBODY);
        assert!(member.s("read") == "ok" && member.s("sealed") == "true", "{member:?}");
        assert!(!outsider.s("read").starts_with("ok"), "an outsider must not get the port: {outsider:?}");
        // Past the socket's mode (opened to everybody here), the broker's own peer check
        // refuses the outsider before any request is answered: still no descriptor.
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(b.socket(), std::fs::Permissions::from_mode(0o666)).unwrap();
        let past_mode = as_uid(&NOBODY);
        std::fs::set_permissions(b.socket(), std::fs::Permissions::from_mode(0o660)).unwrap();
        assert!(
            past_mode.s("read").starts_with("error:") && past_mode.1.contains("[permission]"),
            "the broker must refuse an outsider that reached its socket: {past_mode:?}"
        );
        (member_read, outsider_read) =
            (member.1.clone(), format!("{}; past the socket mode: {}", outsider.1, past_mode.1));
    }
    figure!(
        13,
        "memfd port by name: reader got {} frames, lost {}, 0 corrupted of frames 1..={lfi}; no port file; \
         group member: {member_read}; outsider: {outsider_read}",
        f.u("delivered"),
        f.u("lost")
    );
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_stop_acquire_cycle_restarts_readers_of_a_memfd_port_and_the_old_one_is_accounted() {
    let dir = TempDir::shm("memfd-cycle");
    let b = Bassd::start_stock(dir.path(), "mfc", &["--port-backing", "memfd"], &[]);
    let first = b.client().acquire(&acquire_req("sim:pattern", 48000, 256, 32, 2)).expect("acquire");
    let (epoch, old) = open_by_broker(&b);
    assert_eq!(epoch, first.epoch);
    wait_for_frame(&old, 256 * 8);
    // Every sample the window holds is the pattern.
    let nfop = old.frames_on_port() as usize;
    let mut bufs = vec![vec![0i32; nfop]; 2];
    let mut nfr = 1;
    let r = {
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        old.get_audio_data(nfop, &mut nfr, &mut outs).unwrap()
    };
    let first_frame = nfr - r.frames as u64;
    let bad = (0..2)
        .flat_map(|c| (0..r.frames).map(move |i| (c, i)))
        .filter(|&(c, i)| bufs[c][i] != pattern_expected(first_frame + i as u64, c as u32))
        .count();
    assert_eq!(bad, 0, "{} frames read from {first_frame}", r.frames);

    b.client().stop().expect("stop");
    assert_eq!(old.info().unwrap().state, Some(State::Stopped));
    let second = b.client().acquire(&acquire_req("sim:pattern", 48000, 256, 32, 2)).expect("acquire");
    assert_eq!(second.epoch, first.epoch + 1, "the epoch continues across memfd ports");
    // The reader of the old port is told, as with files.
    let t = Instant::now();
    match old.wait(u64::MAX >> 8, PATIENCE) {
        Err(Error::Restarted) => {}
        other => panic!("a reader of the superseded port must see Restarted, got {other:?}"),
    }
    assert!(t.elapsed() < PATIENCE);
    let (epoch2, new) = open_by_broker(&b);
    assert_eq!((epoch2, new.epoch()), (second.epoch, second.epoch));
    wait_for_frame(&new, 256 * 4);
    // The old memfd lives while we map it; once unmapped, the broker's ledger lets it go:
    // a third Acquire then succeeds for the broker's own user either way, so look at the
    // broker's descriptors instead: the old port's memfd leaves the broker's fd table.
    let memfds =
        |pid: u32| bass_faults::fd_targets(pid).iter().filter(|t| t.contains("memfd:bass-port")).count();
    let held = memfds(b.pid());
    drop(old);
    let released = wait_until(PATIENCE, || memfds(b.pid()) < held);
    assert!(
        released,
        "the broker still holds {} port memfds after the old port's reader left",
        memfds(b.pid())
    );
    let after = memfds(b.pid());
    // The CLI follows: `bass acquire --wait` opens the new port (no file: through the broker).
    let out = std::process::Command::new(bin_path("bass", "BASS_CLI"))
        .args([
            "--name",
            "mfc",
            "acquire",
            "sim:pattern",
            "--rate",
            "48000",
            "--frames",
            "256",
            "--chunks",
            "32",
        ])
        .arg("--wait")
        .env("BASS_RUNTIME_DIR", dir.path())
        .output()
        .expect("run bass");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && text.contains("first chunk published"),
        "bass acquire --wait on a memfd broker: {} {text} {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    figure!(
        13,
        "memfd Stop/Acquire: epoch {} -> {}, the old port's reader got Restarted, {} window frames exact; \
         broker port memfds {held} while a reader mapped the old port, {} after",
        first.epoch,
        second.epoch,
        r.frames,
        after
    );
}
