//! A root broker on a shared machine, against a hostile normal user (uid 65534,
//! through setpriv; the group is the numeric test gid 4242, so no user or group is created).
//!
//! - item 1: symlinks and foreign files planted in a world-writable runtime directory are
//!   refused (the link target is neither written nor created);
//! - item 2: a root broker's default runtime directory is /run/bass (root-owned, 0755), which
//!   clients find before /dev/shm; control clients refuse a socket served by an unexpected
//!   uid unless BASS_BROKER_UID names it; the lock's text is never echoed;
//! - item 5: members of --group cannot take the connections kept for root.
//!
//! Each test skips (and says so) when not run as root with setpriv available; with
//! `BASS_TESTS_NO_SKIP=1` (CI as root) it fails instead.

use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use bass_faults::{figure, test_group, Agent};
use bass_test_support::{
    as_nobody, bin_path, impersonation_missing, nobody_in_group, setpriv, skip, wait_until, Bassd, TempDir,
    NOBODY,
};

/// A world-writable (1777) runtime directory, like /dev/shm.
fn sticky_dir(tag: &str) -> TempDir {
    let d = TempDir::shm(tag);
    std::fs::set_permissions(d.path(), std::fs::Permissions::from_mode(0o1777)).unwrap();
    d
}

/// Runs root `bassd --name NAME` in `dir` expecting it to refuse to start; returns its
/// stderr (panics if it is still running after 20 s).
fn bassd_refuses(dir: &Path, name: &str) -> String {
    let mut child = Command::new(bin_path("bassd", "BASS_BASSD"))
        .args(["--name", name, "--rt-priority", "0"])
        .env("BASS_RUNTIME_DIR", dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn bassd");
    let exited = wait_until(Duration::from_secs(20), || child.try_wait().ok().flatten().is_some());
    if !exited {
        let _ = child.kill();
        let _ = child.wait();
        panic!("bassd --name {name} started despite what was planted in {}", dir.display());
    }
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(1), "bassd --name {name}: {:?}", out.status);
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn files_planted_in_the_runtime_directory_are_refused_not_followed() {
    if skip(impersonation_missing()) {
        figure!("14.1", "SKIPPED: needs root and setpriv");
        return;
    }
    let d = sticky_dir("plant");
    let victims = TempDir::shm("victims");
    let victim = victims.join("v");
    std::fs::write(&victim, "data\n").unwrap();
    let dangling = victims.join("created-by-root");
    let dir = d.path().to_str().unwrap();
    let mut lines = Vec::new();
    let cases: [(&str, Vec<String>, &str); 4] = [
        (
            "lk",
            vec!["ln".into(), "-s".into(), victim.display().to_string(), format!("{dir}/bass-lk.lock")],
            "symbolic link",
        ),
        (
            "dang",
            vec!["ln".into(), "-s".into(), dangling.display().to_string(), format!("{dir}/bass-dang.lock")],
            "symbolic link",
        ),
        ("own", vec!["touch".into(), format!("{dir}/bass-own.lock")], "owned by uid 65534"),
        (
            "sk",
            vec!["ln".into(), "-s".into(), victim.display().to_string(), format!("{dir}/bass-sk.sock")],
            "Symlink",
        ),
    ];
    for (name, cmd, why) in &cases {
        let args: Vec<&str> = cmd[1..].iter().map(String::as_str).collect();
        let out = as_nobody(&cmd[0], &args);
        assert!(out.status.success(), "planting for {name}: {}", String::from_utf8_lossy(&out.stderr));
        let err = bassd_refuses(d.path(), name);
        assert!(err.contains(why), "{name}: {err}");
        lines.push(format!("{name}: {}", err.trim()));
    }
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "data\n", "the symlink target was written");
    assert!(!dangling.exists(), "the dangling symlink's target was created");
    figure!(
        "14.1",
        "planted by uid 65534 in a 1777 directory, all refused, targets untouched: {}",
        lines.join(" | ")
    );
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn the_lock_holders_text_is_never_echoed() {
    let d = TempDir::shm("locktext");
    let lock = d.join("bass-busy.lock");
    std::fs::write(&lock, "\x1b]0;evil\x07\x1b[2J 1234\n").unwrap();
    let f = std::fs::File::open(&lock).unwrap();
    rustix::fs::flock(&f, rustix::fs::FlockOperation::NonBlockingLockExclusive).unwrap();
    let err = bassd_refuses(d.path(), "busy");
    assert!(err.contains("already running (pid unknown"), "{err}");
    assert!(!err.contains('\x1b') && !err.contains("evil"), "the lock's text was echoed: {err:?}");
    figure!("14.2", "a lock holding escape sequences: {}", err.trim());
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn clients_refuse_a_control_socket_served_by_another_user() {
    if skip(impersonation_missing()) {
        figure!("14.2", "SKIPPED socket owner check: needs root and setpriv");
        return;
    }
    let d = sticky_dir("squat");
    let bassd = bin_path("bassd", "BASS_BASSD");
    let mut impostor = setpriv(&NOBODY, &bassd)
        .args(["--name", "imp", "--rt-priority", "0"])
        .env("BASS_RUNTIME_DIR", d.path())
        .env("BASS_LOG", "error")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .expect("spawn the impostor");
    let sock = d.join("bass-imp.sock");
    assert!(wait_until(Duration::from_secs(20), || sock.exists()), "the impostor did not start");
    let bass = bin_path("bass", "BASS_CLI");
    let status = |extra: &[(&str, &str)]| {
        let mut c = Command::new(&bass);
        c.args(["--name", "imp", "status"]).env("BASS_RUNTIME_DIR", d.path()).env_remove("BASS_BROKER_UID");
        for (k, v) in extra {
            c.env(k, v);
        }
        c.output().unwrap()
    };
    let refused = status(&[]);
    let err = String::from_utf8_lossy(&refused.stderr).into_owned();
    let trusted = status(&[("BASS_BROKER_UID", "65534")]);
    // setpriv exec'd bassd in place: the child is the impostor broker.
    bass_test_support::send_signal(impostor.id(), libc::SIGTERM);
    let st = impostor.wait().expect("wait for the impostor");
    assert!(st.success(), "the impostor bassd ended with {st} on SIGTERM");
    assert!(!refused.status.success(), "root's client talked to uid 65534's broker");
    assert!(err.contains("served by uid 65534") && err.contains("BASS_BROKER_UID"), "{err}");
    assert!(trusted.status.success(), "BASS_BROKER_UID=65534: {}", String::from_utf8_lossy(&trusted.stderr));
    figure!("14.2", "a control socket served by uid 65534, root client: {}", err.trim());
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_root_broker_lives_in_run_bass_and_clients_find_it_before_dev_shm() {
    if skip(impersonation_missing()) {
        figure!("14.2", "SKIPPED /run/bass: needs root and setpriv");
        return;
    }
    let name = format!("t14sys-{}", std::process::id());
    let sys = PathBuf::from(bassport::paths::SYSTEM_RUNTIME_DIR);
    let group = test_group().to_string();
    // A squatter's files under the same name in /dev/shm must not shadow the system broker.
    let squat = PathBuf::from("/dev/shm").join(format!("bass-{name}.sock"));
    let out = as_nobody("touch", &[squat.to_str().unwrap()]);
    assert!(out.status.success());
    let mut b = Command::new(bin_path("bassd", "BASS_BASSD"))
        .args(["--name", &name, "--rt-priority", "0", "--group", &group])
        .env_remove("BASS_RUNTIME_DIR")
        .env("BASS_LOG", "error")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .expect("spawn bassd");
    let sock = sys.join(format!("bass-{name}.sock"));
    let up = wait_until(Duration::from_secs(20), || sock.exists());
    let meta = std::fs::symlink_metadata(&sys);
    let member = setpriv(&nobody_in_group(test_group()), bin_path("bass", "BASS_CLI"))
        .args(["--name", &name, "acquire", "sim:pattern", "--rate", "8000", "--frames", "80"])
        .env_remove("BASS_RUNTIME_DIR")
        .output()
        .unwrap();
    bass_test_support::send_signal(b.id(), libc::SIGTERM);
    let st = b.wait().expect("wait for bassd");
    // What bassd left behind (its port; the lock and socket it removes itself), if anything.
    for ext in ["port", "lock", "sock"] {
        let _ = std::fs::remove_file(sys.join(format!("bass-{name}.{ext}")));
    }
    std::fs::remove_file(&squat).expect("remove the squatter's file");
    assert!(st.success(), "the root bassd ended with {st} on SIGTERM");
    assert!(up, "no control socket appeared in {}", sys.display());
    let meta = meta.unwrap();
    assert!(meta.is_dir() && meta.uid() == 0 && meta.mode() & 0o022 == 0, "{}: {meta:?}", sys.display());
    let text =
        format!("{}{}", String::from_utf8_lossy(&member.stdout), String::from_utf8_lossy(&member.stderr));
    assert!(member.status.success() && text.contains(sys.to_str().unwrap()), "group member: {text}");
    figure!(
        "14.2",
        "root bassd without BASS_RUNTIME_DIR: {} mode {:o} owner uid {}; a group member's `bass acquire` found it there despite a squatted {}: {}",
        sys.display(),
        meta.mode() & 0o7777,
        meta.uid(),
        squat.display(),
        text.trim()
    );
}

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn group_members_cannot_take_the_connections_kept_for_root() {
    if skip(impersonation_missing()) {
        figure!("14.5", "SKIPPED: needs root and setpriv");
        return;
    }
    let d = TempDir::shm("reserved");
    std::fs::set_permissions(d.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    let group = test_group().to_string();
    let b = Bassd::start_stock(d.path(), "res", &["--group", &group], &[]);
    let sock = b.socket();
    let member = nobody_in_group(test_group());
    let member: Vec<&str> = member.iter().map(String::as_str).collect();
    let mut agent = Agent::spawn_setpriv(
        &member,
        &["hold-connections", "--socket", sock.to_str().unwrap(), "--name", "res", "--n", "130"],
    );
    let line = agent.expect_line("held");
    let f: Vec<&str> = line.split_whitespace().collect();
    let (held, refused): (usize, usize) = (f[1].parse().unwrap(), f[3].parse().unwrap());
    let max = bassd::server::MAX_CLIENTS;
    let reserved = bassd::server::RESERVED_CLIENTS;
    assert_eq!((held, refused), (max - reserved, 130 - (max - reserved)), "{line}");
    assert!(line.contains("too_many_control_connections"), "{line}");
    // Root still gets in, on every reserved connection.
    let mut roots = Vec::new();
    for i in 0..reserved {
        let mut c = b.try_client().unwrap_or_else(|e| panic!("root connection {i}: {e}"));
        c.status().unwrap_or_else(|e| panic!("root connection {i} while members hold {held}: {e}"));
        roots.push(c);
    }
    let over = b.try_client().and_then(|mut c| c.status());
    assert!(over.is_err(), "more than {max} connections were served");
    agent.close_stdin();
    // The member's agent let go of every connection and exited cleanly, with the same count.
    let done = agent.result();
    assert_eq!((done.u("held") as usize, done.u("refused") as usize), (held, refused), "{}", done.1);
    figure!(
        "14.5",
        "a group member opening 130 connections holds {held} ({refused} refused: too many); root then opens the {reserved} kept connections, all served; the {}th is refused",
        max + 1
    );
}
