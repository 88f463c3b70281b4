//! Item 3 (port level) — readers SIGKILLed mid-read and mid-wait, 100 times each, while a
//! writer process publishes and two long-lived readers read.
//!
//! Pass: the writer keeps publishing (still alive, lastFrameIndex advancing after the
//! kills); the long-lived readers get 0 corrupted samples and exact accounting; the
//! writer's open file descriptors are the same before and after; the runtime directory
//! holds only the port file (a reader creates nothing, so nothing can leak).
//! The broker variant (bassd, control connections) is in killed_control_clients.rs.

use std::time::{Duration, Instant};

use bass_faults::{current_syscall, fd_targets, figure, Agent, Rng};
use bass_test_support::TempDir;

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn readers_killed_mid_read_and_mid_wait_leak_nothing_and_disturb_no_one() {
    let kills_per_mode: usize =
        std::env::var("BASS_FAULTS_KILLS").ok().and_then(|s| s.parse().ok()).unwrap_or(100);
    let seed = bass_faults::seed();
    let mut rng = Rng::with_seed(seed);
    let dir = TempDir::shm("kill");
    let path = dir.join("bass-kill.port");
    let p = path.to_str().unwrap();
    let mut w = Agent::writer_held(p, 64, 8, &["--pace-us", "1000"]);
    let mut steady: Vec<Agent> = [("copy", "64", "200"), ("wait", "128", "0")]
        .iter()
        .map(|(m, n, pause)| {
            Agent::spawn(&["reader", "--port", p, "--mode", m, "--n", n, "--pause-us", pause])
        })
        .collect();
    for r in &mut steady {
        r.expect_line("ready");
    }
    w.send("go");
    let lfi_of = || bassport::Port::open_path(&path).unwrap().info().unwrap().last_frame_index;
    // The writer publishes (past its set-up) before its descriptors are counted.
    bass_test_support::eventually("the writer's first chunks", || (lfi_of() >= 64 * 8).then_some(()));
    let fds_before = fd_targets(w.pid());
    let entries_before = dir.entries();
    let started = Instant::now();
    let mut in_futex = 0;
    let mut running = 0;
    for mode in ["read", "wait"] {
        for _ in 0..kills_per_mode {
            let mut v = Agent::spawn(&["victim", "--port", p, "--mode", mode]);
            v.expect_line("ready");
            std::thread::sleep(Duration::from_micros(rng.u64(..5000)));
            let sc = current_syscall(v.pid());
            if sc == "202" {
                in_futex += 1;
            } else if sc == "running" {
                running += 1;
            }
            v.signal(libc::SIGKILL);
            let (status, _) = v.finish();
            use std::os::unix::process::ExitStatusExt;
            assert_eq!(status.signal(), Some(libc::SIGKILL), "victim ended otherwise: {status}");
        }
    }
    let kill_time = started.elapsed();
    let lfi_after_kills = lfi_of();
    assert!(
        bass_test_support::wait_until(Duration::from_secs(5), || lfi_of() > lfi_after_kills + 64),
        "the writer stopped publishing after the kills"
    );
    let fds_after = fd_targets(w.pid());
    let entries_after = dir.entries();
    w.close_stdin();
    let wf = w.result();
    let mut delivered = 0;
    for (k, r) in steady.into_iter().enumerate() {
        let f = r.result();
        assert_eq!(f.u("corrupted"), 0, "steady reader {k} got corrupted samples");
        assert_eq!(f.u("delivered") + f.u("lost"), f.u("requested"), "steady reader {k} accounting");
        assert_eq!(f.u("requested"), wf.u("last"), "steady reader {k} must cover every frame");
        delivered += f.u("delivered");
    }
    figure!(
        3,
        "port level: {} readers SIGKILLed ({} mid-read, {} mid-wait; at the kill {running} were running, {in_futex} blocked in futex) in {:.1} s (seed {seed}); writer fds {} before, {} after; runtime dir {:?} before, {:?} after; steady readers delivered {delivered} frames, 0 corrupted; writer max lateness {} us",
        2 * kills_per_mode,
        kills_per_mode,
        kills_per_mode,
        kill_time.as_secs_f64(),
        fds_before.len(),
        fds_after.len(),
        entries_before,
        entries_after,
        wf.u("max_late_us")
    );
    assert_eq!(fds_before, fds_after, "the writer's file descriptors changed");
    assert_eq!(entries_after, vec!["bass-kill.port".to_string()], "files appeared in the runtime directory");
    assert!(in_futex >= kills_per_mode / 2, "too few victims were caught blocked in the futex wait");
}
