//! bassd under a service manager, against a fake of systemd's side (tests/support's
//! `FakeManager`: NOTIFY_SOCKET datagrams with SCM_RIGHTS, the fd store, LISTEN_FDS on the
//! next start). Real bassd processes, real ports, a reader that keeps reading across the
//! restarts: it must see the same epoch, frame indices that go on, the frames missed while no
//! broker ran as zeros counted exactly by the port's gap counter, and the pattern again after.
//! The same against real systemd: tests/systemd/run.sh.

use std::os::fd::OwnedFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bass_test_support::*;
use bassclient::control::OpenedPort;
use bassclient::format::{chunk_flags, error_code, State};
use bassclient::testsignal::pattern_sample;
use bassclient::{Error, Port};

const RATE: u32 = 48_000;
const NFPC: u32 = 480;
const ACQUIRE: [&str; 10] =
    ["--acquire", "sim:pattern", "--rate", "48000", "--frames", "480", "--chunks", "400", "--channels", "2"];

/// A supervised broker: the fake manager's environment, these arguments, the fds it hands back.
fn start(
    dir: &std::path::Path,
    name: &str,
    mgr: &FakeManager,
    args: &[&str],
    handed: Vec<(String, OwnedFd)>,
) -> Bassd {
    let env = mgr.env(Some(1_000_000));
    let env: Vec<(&str, &str)> = env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    Bassd::builder(dir, name).args(args).envs(&env).handed_fds(handed).start()
}

/// Opens the broker's port as a reader would (a memfd's descriptor over the socket, or the path).
fn open(b: &Bassd) -> Port {
    match b.client().open_port().expect("open-port") {
        OpenedPort::Fd { fd, .. } => Port::from_fd(fd, &b.name).expect("map the port"),
        OpenedPort::File(p) => Port::open_path(&p).expect("open the port file"),
    }
}

/// What a reader saw, chunk by chunk.
#[derive(Default, Debug)]
struct Seen {
    first: u64,
    next: u64,
    loss: u64,
    zero_frames: u64,
    gap_chunks: u64,
    /// (first frame of a run of the pattern, port frame - device frame in it).
    shifts: Vec<(u64, u64)>,
    bad: Vec<String>,
    end: Option<String>,
}

/// Reads chunk after chunk from the live edge until `stop`, checking every sample: a frame
/// is either all zeros (missed) or the pattern of some device frame; a new shift may only
/// begin after zeros (the restart's gap).
fn reader(port: Port, stop: Arc<AtomicBool>) -> JoinHandle<Seen> {
    std::thread::spawn(move || {
        let n = NFPC as usize;
        let mut seen = Seen::default();
        let mut nfr = port.info().unwrap().last_frame_index + 1;
        seen.first = nfr;
        let (mut l, mut r) = (vec![0i32; n], vec![0i32; n]);
        let mut after_zero = true;
        while !stop.load(Ordering::Acquire) {
            if let Err(e) = port.wait(nfr + u64::from(NFPC) - 1, Duration::from_secs(15)) {
                seen.end = Some(e.to_string());
                break;
            }
            let at = nfr;
            let got = match port.get_audio_data(n, &mut nfr, &mut [&mut l, &mut r]) {
                Ok(g) => g,
                Err(e) => {
                    seen.end = Some(format!("getAudioData at {at}: {e}"));
                    break;
                }
            };
            seen.loss += got.loss;
            let first = nfr - got.frames as u64;
            if port.chunk_info(first).is_ok_and(|c| c.flags & chunk_flags::GAP != 0) {
                seen.gap_chunks += 1;
            }
            for i in 0..got.frames {
                let f = first + i as u64;
                if l[i] == 0 && r[i] == 0 {
                    seen.zero_frames += 1;
                    after_zero = true;
                    continue;
                }
                let device = u64::from((l[i] as u32) >> 6);
                let shift = f.wrapping_sub(device) & 0x03FF_FFFF;
                match seen.shifts.last() {
                    Some(&(_, s)) if s == shift => {}
                    _ if after_zero => seen.shifts.push((f, shift)),
                    _ => seen.bad.push(format!("frame {f}: device frame {device} without a gap before")),
                }
                after_zero = false;
                let d = f - shift;
                if (l[i], r[i]) != (pattern_sample(d, 0), pattern_sample(d, 1)) {
                    seen.bad.push(format!(
                        "frame {f}: ({}, {}) is not the pattern of device frame {d}",
                        l[i], r[i]
                    ));
                }
            }
            seen.next = nfr;
        }
        seen
    })
}

/// Frames on the port's timeline between `stopped` and `resumed`.
fn frames_in(d: Duration) -> u64 {
    (d.as_secs_f64() * f64::from(RATE)) as u64
}

fn ready(mgr: &mut FakeManager) {
    assert!(mgr.wait_for("READY=1", PATIENCE).is_some(), "no READY=1; got {:?}", mgr.notices);
}

/// The broker's Status once its acquisition runs: READY comes when the control socket
/// serves, while the device of the start-up (or taken-back) acquisition may still be opening
/// (Status shows epoch 0 until then).
fn acquired(b: &Bassd) -> bassclient::control::Status {
    let t0 = Instant::now();
    loop {
        let st = b.client().status().unwrap();
        if st.epoch != 0 {
            return st;
        }
        assert!(t0.elapsed() < PATIENCE, "no acquisition running; log:\n{}", b.log_text());
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Waits until the store holds the port and its record.
fn stored(mgr: &mut FakeManager) {
    let t0 = Instant::now();
    while mgr.stored_names() != ["bass-port", "bass-acquisition"] {
        assert!(
            t0.elapsed() < PATIENCE,
            "the store holds {:?}; notices {:?}",
            mgr.stored_names(),
            mgr.notices
        );
        mgr.recv(Duration::from_millis(50));
    }
}

/// Runs a broker, then restarts it once per `kills` signal with the store handed back,
/// while one reader reads; returns the reader's account and the last broker.
fn ride_through(backing: &str, kills: &[i32]) -> (Seen, Bassd, TempDir, Vec<Duration>) {
    let dir = TempDir::new("bass-supervised");
    let mut mgr = FakeManager::new(dir.path());
    let mut args = ACQUIRE.to_vec();
    args.extend(["--port-backing", backing]);
    let mut b = start(dir.path(), "sup", &mgr, &args, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    let port = open(&b);
    let info = port.info().unwrap();
    assert_eq!(info.version_minor, bassclient::format::VERSION_MINOR);
    wait_frame(&port, info.last_frame_index + u64::from(NFPC));
    let epoch = port.epoch();
    let stop = Arc::new(AtomicBool::new(false));
    let r = reader(port, stop.clone());
    let mut downtimes = Vec::new();
    for &sig in kills {
        std::thread::sleep(Duration::from_millis(400));
        // From the signal: the gap starts at the end of the last chunk published before it
        // (wait_exit notices the exit up to 10 ms late, so it cannot be the start).
        let gone = Instant::now();
        b.signal(sig);
        b.wait_exit();
        std::thread::sleep(Duration::from_millis(300));
        b = start(dir.path(), "sup", &mgr, &args, mgr.handed());
        ready(&mut mgr);
        let st = acquired(&b);
        assert_eq!(
            st.epoch,
            epoch,
            "the restarted broker goes on with the same epoch; log:\n{}",
            b.log_text()
        );
        // The first new chunk: the port's frame index passes where it was.
        let p2 = open(&b);
        wait_frame(&p2, st.last_frame_index + u64::from(NFPC));
        downtimes.push(gone.elapsed());
        stored(&mut mgr);
    }
    std::thread::sleep(Duration::from_millis(400));
    stop.store(true, Ordering::Release);
    let seen = r.join().unwrap();
    (seen, b, dir, downtimes)
}

fn check_ridden(seen: &Seen, b: &Bassd, restarts: usize, downtimes: &[Duration]) {
    assert_eq!(seen.end, None, "the reader was ended; log:\n{}", b.log_text());
    assert!(seen.bad.is_empty(), "{:?}", &seen.bad[..seen.bad.len().min(5)]);
    assert_eq!(seen.loss, 0, "a reader that keeps up loses nothing across a restart");
    assert_eq!(seen.shifts.len(), restarts + 1, "one run of the pattern per broker: {:?}", seen.shifts);
    let info = open(b).info().unwrap();
    assert_eq!(info.state, Some(State::Capturing));
    // Counted exactly: every zero frame the reader saw is in the port's gap counter, and
    // nothing else is (the pattern has no all-zero frame).
    assert_eq!(seen.zero_frames, info.gap_frames, "zero frames read vs the port's gap_frames");
    for (i, d) in downtimes.iter().enumerate() {
        eprintln!(
            "restart {}: {} frames missed as GAP in all so far; signal to first new chunk {d:?}",
            i + 1,
            info.gap_frames
        );
    }
    // No more missed than the time no broker ran, and at least the 300 ms pause. The time no
    // broker ran is bounded by the measured downtimes (signal to the new broker's first chunk)
    // plus what the old capture thread may have owed when the signal came: 5 chunks (50 ms)
    // for a loaded machine. A timeline error (a gap counted twice, a restart measured from
    // the wrong chunk) is a whole downtime, over 14 000 frames.
    let max: u64 = downtimes.iter().map(|d| frames_in(*d) + u64::from(5 * NFPC)).sum();
    assert!(info.gap_frames >= frames_in(Duration::from_millis(300)) * restarts as u64, "{info:?}");
    assert!(info.gap_frames <= max, "gap {} > {max} frames for downtimes {downtimes:?}", info.gap_frames);
    assert!(seen.gap_chunks > 0, "whole missed chunks are flagged GAP");
}

#[test]
fn a_memfd_port_rides_through_a_restart_and_a_crash_with_the_gap_counted() {
    let (seen, b, _dir, downtimes) = ride_through("memfd", &[libc::SIGTERM, libc::SIGKILL]);
    check_ridden(&seen, &b, 2, &downtimes);
    let log = b.log_text();
    assert!(log.contains("resuming the acquisition"), "{log}");
}

#[test]
fn a_file_port_rides_through_a_restart_with_the_gap_counted() {
    let (seen, b, _dir, downtimes) = ride_through("file", &[libc::SIGTERM]);
    check_ridden(&seen, &b, 1, &downtimes);
}

#[test]
fn a_restart_with_another_command_line_is_a_new_epoch_readers_are_told() {
    let dir = TempDir::new("bass-supervised");
    let mut mgr = FakeManager::new(dir.path());
    let mut b = start(dir.path(), "cfg", &mgr, &ACQUIRE, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    let port = open(&b);
    let last = wait_frame(&port, 1);
    b.signal(libc::SIGTERM);
    b.wait_exit();
    let mut other = ACQUIRE.to_vec();
    other.extend(["--max-port-bytes", "100000000"]);
    let b2 = start(dir.path(), "cfg", &mgr, &other, mgr.handed());
    ready(&mut mgr);
    assert!(matches!(port.wait(last + 100 * u64::from(NFPC), PATIENCE), Err(Error::Restarted)));
    let st = acquired(&b2);
    assert_eq!(st.epoch, port.epoch() + 1, "a new acquisition: the next epoch");
    assert!(b2.log_text().contains("another command line"), "{}", b2.log_text());
}

#[test]
fn a_stop_empties_the_store_and_a_later_sigterm_stops_the_port() {
    let dir = TempDir::new("bass-supervised");
    let mut mgr = FakeManager::new(dir.path());
    let mut b = start(dir.path(), "stop", &mgr, &ACQUIRE, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    let port = open(&b);
    assert_eq!(port.info().unwrap().writer_pid, b.pid());
    b.client().stop().unwrap();
    let t0 = Instant::now();
    while !mgr.store.is_empty() {
        assert!(t0.elapsed() < PATIENCE, "the store still holds {:?}", mgr.stored_names());
        mgr.recv(Duration::from_millis(50));
    }
    b.signal(libc::SIGTERM);
    b.wait_exit();
    assert_eq!(port.info().unwrap().state, Some(State::Stopped));
}

#[test]
fn the_watchdog_is_fed_while_capturing_and_not_once_the_device_stalled() {
    let dir = TempDir::new("bass-supervised");
    let mut mgr = FakeManager::new(dir.path());
    let env = mgr.env(Some(300_000));
    let env: Vec<(&str, &str)> = env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    let b = Bassd::builder(dir.path(), "wd")
        .stall_ms(Some(400))
        .args(&[
            "--acquire",
            "sim:stall",
            "--rate",
            "8000",
            "--frames",
            "80",
            "--chunks",
            "100",
            "--channels",
            "1",
        ])
        .envs(&env)
        .start();
    ready(&mut mgr);
    let port = open(&b);
    // sim:stall delivers half a second, then nothing: the broker's stall watchdog ends the
    // acquisition (DEVICE_STALLED) and the service manager's watchdog is no longer fed.
    let t0 = Instant::now();
    while port.info().unwrap().state != Some(State::Error) {
        assert!(t0.elapsed() < PATIENCE, "no stall");
        mgr.recv(Duration::from_millis(20));
    }
    assert_eq!(port.info().unwrap().error_code, error_code::DEVICE_STALLED);
    let fed_before = mgr.notices.iter().filter(|n| n.has("WATCHDOG=1")).count();
    assert!(fed_before >= 2, "fed while capturing: {:?}", mgr.notices);
    let after = mgr.collect(Duration::from_millis(1500));
    assert!(!after.iter().any(|n| n.has("WATCHDOG=1")), "fed after the stall: {after:?}");
    let status: Vec<&str> = after.iter().chain(&mgr.notices).filter_map(|n| n.value("STATUS")).collect();
    assert!(status.iter().any(|s| s.contains("device stalled")), "{status:?}");
}

#[test]
fn without_a_service_manager_a_sigterm_stops_the_port_as_before() {
    let dir = TempDir::new("bass-supervised");
    let mut b = Bassd::start(dir.path(), "plain", &ACQUIRE, &[]);
    let port = b.port_once_acquired();
    wait_frame(&port, 1);
    b.signal(libc::SIGTERM);
    b.wait_exit();
    assert!(matches!(port.wait(u64::MAX / 2, PATIENCE), Err(Error::Stopped { .. })));
}
