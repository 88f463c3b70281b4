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
use basskit::testsignal::pattern_sample;
use bassport::control::OpenedPort;
use bassport::format::{chunk_flags, error_code, State};
use bassport::{Error, Port};

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
fn acquired(b: &Bassd) -> bassport::control::Status {
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
    assert_eq!(info.version_minor, bassport::format::VERSION_MINOR);
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

/// A routine restart (SIGTERM, the successor takes the port back from the store) is logged
/// as what it is, at INFO: no WARN about a port "left capturing by a broker that is gone"
/// (issue 33 item 10: every `systemctl restart` logged one).
#[test]
fn a_routine_restart_logs_no_warning_about_the_port_it_takes_back() {
    let dir = TempDir::new("bass-supervised");
    let mut mgr = FakeManager::new(dir.path());
    let mut b = start(dir.path(), "routine", &mgr, &ACQUIRE, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    b.signal(libc::SIGTERM);
    b.wait_exit();
    let b2 = start(dir.path(), "routine", &mgr, &ACQUIRE, mgr.handed());
    ready(&mut mgr);
    acquired(&b2);
    let log = b2.log_text();
    assert!(
        log.lines()
            .any(|l| l.contains("left capturing by the previous broker") && l.contains("takes it back")),
        "{log}"
    );
    assert!(!log.lines().any(|l| l.contains("WARN") && l.contains("left capturing")), "{log}");
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
    // READY comes when the socket serves; the start-up acquisition's device may still be
    // opening (no port to hand out yet).
    acquired(&b);
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

// ---- Readers that chose to wait follow every continuation (a resume after the grace, after
// a stalled device, a memfd successor): a callback stream (events, tiling) and the blocking
// reader loop of docs/c-api.md, through the C ABI, by name. These tests share one runtime
// directory (the C ABI opens ports by name, through $BASS_RUNTIME_DIR), each broker its name.

/// The runtime directory of the following tests, set as this process's $BASS_RUNTIME_DIR.
fn shared_runtime() -> &'static std::path::Path {
    static DIR: std::sync::OnceLock<TempDir> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let d = TempDir::new("bass-follow");
        std::env::set_var("BASS_RUNTIME_DIR", d.path());
        d
    })
    .path()
}

/// One thing a stream saw: a block (epoch, first frame, frames, lost, zero frames) or an event.
#[derive(Debug, Clone, PartialEq)]
enum Seen2 {
    Block { epoch: u64, first: u64, frames: u64, lost: u64, zeros: u64, flags: u32 },
    Event(String),
}

/// A callback stream on broker `name`'s port (by name), every event answered "go on".
fn follow_stream(name: &str) -> (bassport::stream::StreamHandle, Arc<std::sync::Mutex<Vec<Seen2>>>) {
    use bassport::stream::{Config, Control, Stream};
    let port = Arc::new(Port::open(name).expect("open the port by name"));
    let log = Arc::new(std::sync::Mutex::new(Vec::new()));
    let (lb, le) = (log.clone(), log.clone());
    let handle = Stream::new(port, Config::default())
        .unwrap()
        .spawn(
            move |b| {
                let zeros = (0..b.frames).filter(|&i| b.sample(0, i) == 0 && b.sample(1, i) == 0).count();
                lb.lock().unwrap().push(Seen2::Block {
                    epoch: b.epoch,
                    first: b.first_frame,
                    frames: b.frames as u64,
                    lost: b.lost,
                    zeros: zeros as u64,
                    flags: b.flags,
                });
                Control::Continue
            },
            move |e| {
                le.lock().unwrap().push(Seen2::Event(format!("{e:?}")));
                Control::Continue
            },
        )
        .unwrap();
    (handle, log)
}

/// The events a stream saw, in order.
fn events(log: &std::sync::Mutex<Vec<Seen2>>) -> Vec<String> {
    let log = log.lock().unwrap();
    log.iter().filter_map(|s| if let Seen2::Event(e) = s { Some(e.clone()) } else { None }).collect()
}

/// Blocks after the last event that starts with `kind` (0 if no such event yet).
fn blocks_after(log: &std::sync::Mutex<Vec<Seen2>>, kind: &str) -> usize {
    let log = log.lock().unwrap();
    match log.iter().rposition(|s| matches!(s, Seen2::Event(e) if e.starts_with(kind))) {
        Some(i) => log[i + 1..].iter().filter(|s| matches!(s, Seen2::Block { .. })).count(),
        None => 0,
    }
}

/// Checks the tiling of what a stream saw: within an epoch every block starts where the one
/// before ended plus its `lost`; a Resumed goes on at the frame after the last block; a
/// Restarted starts its epoch at `resume_at`. Returns (frames lost, zero frames delivered).
fn check_tiling(log: &[Seen2]) -> (u64, u64) {
    let (mut next, mut epoch, mut lost, mut zeros) = (None::<u64>, None::<u64>, 0, 0);
    for s in log {
        match s {
            Seen2::Block { epoch: e, first, frames, lost: l, zeros: z, flags } => {
                if let (Some(n), Some(ep)) = (next, epoch) {
                    assert_eq!(*e, ep, "a block of another epoch without a Restarted: {log:?}");
                    assert_eq!(*first, n + l, "block at {first} after {n} + lost {l}");
                }
                // Zeros only where the writer missed frames: GAP chunks, or a chunk that
                // starts with the last missed frames and goes on with data (DISCONTINUITY).
                let missed = chunk_flags::GAP | chunk_flags::DISCONTINUITY;
                assert!(
                    *z == 0 || flags & missed != 0,
                    "zero frames without GAP or DISCONTINUITY at {first}"
                );
                (next, epoch) = (Some(first + frames), Some(*e));
                lost += l;
                zeros += z;
            }
            Seen2::Event(e) => {
                let field = |k: &str| -> Option<u64> {
                    let at = e.find(&format!("{k}: "))? + k.len() + 2;
                    e[at..].split(|c: char| !c.is_ascii_digit()).next()?.parse().ok()
                };
                if e.starts_with("Resumed") {
                    assert_eq!(field("epoch"), epoch, "{e}");
                    assert_eq!(field("resume_at"), next, "a resume goes on after the last block: {e}");
                } else if e.starts_with("Restarted") {
                    (next, epoch) = (field("resume_at"), field("epoch"));
                }
            }
        }
    }
    (lost, zeros)
}

/// What the reader loop of docs/c-api.md saw: the codes of its waits that were not BASS_OK
/// (consecutive repeats once), its blocks (epoch, first frame, frames, loss).
#[derive(Default, Debug)]
struct DocsReader {
    codes: Vec<bassclient::bass_result>,
    blocks: Vec<(u64, u64, u64, u64)>,
}

/// The reader loop of docs/c-api.md, "Reading", call for call through the C ABI (N = one
/// chunk), until `stop`.
fn docs_reader(name: &str, stop: Arc<AtomicBool>, seen: Arc<std::sync::Mutex<DocsReader>>) -> JoinHandle<()> {
    use bassclient::*;
    let name = std::ffi::CString::new(name).unwrap();
    std::thread::spawn(move || {
        const N: usize = NFPC as usize;
        let (mut left, mut right) = (vec![0i32; N], vec![0i32; N]);
        let mut port: *mut bass_port = std::ptr::null_mut();
        // SAFETY: every pointer passed is valid for the call (a C string, out-pointers to
        // locals, buffers of N samples); `port` is a handle the library gave.
        unsafe {
            assert_eq!(bass_port_open(name.as_ptr(), &mut port), bass_result::BASS_OK);
            let mut info = std::mem::zeroed::<bass_port_info>();
            bass_port_get_info(port, &mut info);
            let mut epoch = info.epoch;
            let mut nfr = info.last_frame_index + 1;
            let mut prev = bass_result::BASS_OK;
            while !stop.load(Ordering::Acquire) {
                let mut lfi = 0;
                let r = bass_port_wait(port, nfr + N as u64 - 1, 1000, &mut lfi);
                if r != bass_result::BASS_OK && r != prev {
                    seen.lock().unwrap().codes.push(r);
                }
                prev = r;
                if r == bass_result::BASS_ERR_RESTARTED {
                    bass_port_close(port);
                    while bass_port_open(name.as_ptr(), &mut port) != bass_result::BASS_OK {
                        std::thread::sleep(Duration::from_millis(10));
                    }
                    bass_port_get_info(port, &mut info);
                    epoch = info.epoch;
                    nfr = 1;
                    continue;
                }
                use bass_result::*;
                if !matches!(
                    r,
                    BASS_OK | BASS_ERR_TIMEOUT | BASS_ERR_STOPPED | BASS_ERR_DEVICE | BASS_ERR_WRITER_GONE
                ) {
                    break;
                }
                let (mut n, mut loss) = (0usize, 0u64);
                bass_get_audio_data(
                    port,
                    N,
                    &mut nfr,
                    left.as_mut_ptr(),
                    right.as_mut_ptr(),
                    &mut n,
                    &mut loss,
                );
                if n > 0 || loss > 0 {
                    seen.lock().unwrap().blocks.push((epoch, nfr - n as u64, n as u64, loss));
                }
                if r != BASS_OK && n == 0 {
                    std::thread::sleep(Duration::from_millis(100));
                }
            }
            bass_port_close(port);
        }
    })
}

/// The docs reader's blocks tile each epoch: each starts where the one before ended plus its
/// loss. Returns the loss in all.
fn check_docs_tiling(seen: &DocsReader) -> u64 {
    let mut loss = 0;
    for w in seen.blocks.windows(2) {
        let ((e0, f0, n0, _), (e1, f1, _, l1)) = (w[0], w[1]);
        if e0 == e1 {
            assert_eq!(f1, f0 + n0 + l1, "docs reader: block at {f1} after {} + loss {l1}", f0 + n0);
        }
        loss += l1;
    }
    loss
}

/// A supervised broker in the shared runtime directory.
fn start_shared(name: &str, mgr: &FakeManager, args: &[&str], handed: Vec<(String, OwnedFd)>) -> Bassd {
    start(shared_runtime(), name, mgr, args, handed)
}

#[test]
fn a_waiting_stream_and_the_docs_reader_follow_a_resume_after_the_restart_grace() {
    let dir = shared_runtime();
    let mgr_dir = TempDir::new("bass-follow-mgr");
    let mut mgr = FakeManager::new(mgr_dir.path());
    let mut args = ACQUIRE.to_vec();
    args.extend(["--restart-grace-ms", "200"]);
    let mut b = start_shared("follow-grace", &mgr, &args, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    let epoch = acquired(&b).epoch;
    let (stream, log) = follow_stream("follow-grace");
    let stop = Arc::new(AtomicBool::new(false));
    let docs = Arc::new(std::sync::Mutex::new(DocsReader::default()));
    let reader = docs_reader("follow-grace", stop.clone(), docs.clone());
    eventually("blocks before the kill", || (log.lock().unwrap().len() >= 5).then_some(()));
    let pid = b.pid();
    b.signal(libc::SIGKILL);
    b.wait_exit();
    // The grace passes: both readers are told the writer is gone, and wait on.
    eventually("WriterGone on the stream and the docs reader", || {
        let docs_told = docs.lock().unwrap().codes.contains(&bassclient::bass_result::BASS_ERR_WRITER_GONE);
        (events(&log).len() == 1 && docs_told).then_some(())
    });
    assert_eq!(events(&log), [format!("WriterGone {{ pid: {pid} }}")]);
    let b2 = start_shared("follow-grace", &mgr, &args, mgr.handed());
    ready(&mut mgr);
    assert_eq!(acquired(&b2).epoch, epoch, "taken back: the same acquisition; log:\n{}", b2.log_text());
    eventually("blocks after the resume", || (blocks_after(&log, "Resumed") >= 20).then_some(()));
    let after = docs.lock().unwrap().blocks.len();
    eventually("docs reader blocks after the resume", || {
        (docs.lock().unwrap().blocks.len() >= after + 20).then_some(())
    });
    stop.store(true, Ordering::Release);
    reader.join().unwrap();
    drop(stream);
    let log = log.lock().unwrap().clone();
    let ev = events(&std::sync::Mutex::new(log.clone()));
    assert_eq!(ev.len(), 2, "{ev:?}");
    assert!(ev[1].starts_with(&format!("Resumed {{ epoch: {epoch}, resume_at: ")), "{ev:?}");
    let info = Port::open("follow-grace").unwrap().info().unwrap();
    let (lost, zeros) = check_tiling(&log);
    // The window (4 s) outlasts the restart: nothing lost, the frames missed are GAP, exactly.
    assert_eq!(lost, 0);
    assert_eq!(zeros, info.gap_frames, "zero frames delivered vs the port's gap_frames");
    assert!(info.gap_frames > 0);
    let d = docs.lock().unwrap();
    use bassclient::bass_result::*;
    assert_eq!(
        d.codes.iter().filter(|&&c| c != BASS_ERR_TIMEOUT).copied().collect::<Vec<_>>(),
        [BASS_ERR_WRITER_GONE]
    );
    assert_eq!(check_docs_tiling(&d), 0);
    assert!(d.blocks.iter().all(|b| b.0 == epoch));
    drop(b2);
    let _ = dir;
}

#[test]
fn a_waiting_stream_and_the_docs_reader_follow_a_stalled_device_through_its_restart() {
    let mgr_dir = TempDir::new("bass-follow-mgr");
    let mut mgr = FakeManager::new(mgr_dir.path());
    let args = [
        "--acquire",
        "sim:stall",
        "--rate",
        "48000",
        "--frames",
        "480",
        "--chunks",
        "400",
        "--channels",
        "2",
        "--stall-ms",
        "300",
    ];
    let mut b = start_shared("follow-stall", &mgr, &args, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    let epoch = acquired(&b).epoch;
    let (stream, log) = follow_stream("follow-stall");
    let stop = Arc::new(AtomicBool::new(false));
    let docs = Arc::new(std::sync::Mutex::new(DocsReader::default()));
    let reader = docs_reader("follow-stall", stop.clone(), docs.clone());
    let device =
        |log: &std::sync::Mutex<Vec<Seen2>>| events(log).iter().filter(|e| e.starts_with("Device")).count();
    eventually("the stall (Device)", || (device(&log) == 1).then_some(()));
    // The service manager's watchdog is no longer fed: it kills the broker and starts it again.
    b.signal(libc::SIGKILL);
    b.wait_exit();
    let b2 = start_shared("follow-stall", &mgr, &args, mgr.handed());
    ready(&mut mgr);
    assert!(b2.log_text().contains("resuming the acquisition") || acquired(&b2).epoch == epoch);
    // The resumed acquisition delivers half a second and stalls again.
    eventually("the second stall", || (device(&log) == 2).then_some(()));
    eventually("the docs reader past the second stall", || {
        let c = &docs.lock().unwrap().codes;
        (c.iter().filter(|&&c| c == bassclient::bass_result::BASS_ERR_DEVICE).count() == 2).then_some(())
    });
    stop.store(true, Ordering::Release);
    reader.join().unwrap();
    drop(stream);
    let log = log.lock().unwrap().clone();
    let ev = events(&std::sync::Mutex::new(log.clone()));
    let kinds: Vec<&str> = ev.iter().map(|e| e.split(' ').next().unwrap()).collect();
    assert_eq!(kinds, ["Device", "Resumed", "Device"], "{ev:?}");
    assert!(ev[0].contains(&format!("code: {}", error_code::DEVICE_STALLED)), "{ev:?}");
    assert!(ev[1].starts_with(&format!("Resumed {{ epoch: {epoch}, ")), "{ev:?}");
    let (lost, zeros) = check_tiling(&log);
    let info = Port::open("follow-stall").unwrap().info().unwrap();
    assert_eq!(lost, 0);
    assert_eq!(zeros, info.gap_frames, "zero frames delivered vs the port's gap_frames");
    // Half a second of the pattern in each run, the stalls' silence as GAP in between.
    assert!(blocks_after(&std::sync::Mutex::new(log.clone()), "Resumed") >= 40);
    let d = docs.lock().unwrap();
    use bassclient::bass_result::*;
    let codes: Vec<_> = d.codes.iter().filter(|&&c| c != BASS_ERR_TIMEOUT).copied().collect();
    assert_eq!(codes, [BASS_ERR_DEVICE, BASS_ERR_DEVICE], "{:?}", d.codes);
    assert_eq!(check_docs_tiling(&d), 0);
    assert!(d.blocks.iter().all(|b| b.0 == epoch));
}

#[test]
fn a_memfd_successor_that_did_not_take_the_port_back_is_a_new_epoch_readers_follow() {
    let mgr_dir = TempDir::new("bass-follow-mgr");
    let mut mgr = FakeManager::new(mgr_dir.path());
    let mut args = ACQUIRE.to_vec();
    args.extend(["--port-backing", "memfd"]);
    let mut b = start_shared("follow-memfd", &mgr, &args, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    let epoch = acquired(&b).epoch;
    let (stream, log) = follow_stream("follow-memfd");
    let stop = Arc::new(AtomicBool::new(false));
    let docs = Arc::new(std::sync::Mutex::new(DocsReader::default()));
    let reader = docs_reader("follow-memfd", stop.clone(), docs.clone());
    eventually("blocks before the kill", || (log.lock().unwrap().len() >= 5).then_some(()));
    b.signal(libc::SIGKILL);
    b.wait_exit();
    // A service manager that lost its store (systemd after a stop and a start): the next
    // broker cannot take the memfd port back and starts a new acquisition.
    let b2 = start_shared("follow-memfd", &mgr, &args, Vec::new());
    ready(&mut mgr);
    assert_eq!(acquired(&b2).epoch, epoch + 1, "the epoch goes on; log:\n{}", b2.log_text());
    eventually("blocks of the new epoch", || (blocks_after(&log, "Restarted") >= 20).then_some(()));
    eventually("the docs reader in the new epoch", || {
        (docs.lock().unwrap().blocks.iter().filter(|b| b.0 == epoch + 1).count() >= 20).then_some(())
    });
    stop.store(true, Ordering::Release);
    reader.join().unwrap();
    drop(stream);
    let log = log.lock().unwrap().clone();
    let ev = events(&std::sync::Mutex::new(log.clone()));
    assert_eq!(ev.len(), 1, "{ev:?}");
    assert!(ev[0].starts_with(&format!("Restarted {{ epoch: {}, resume_at: 1 }}", epoch + 1)), "{ev:?}");
    let (lost, _) = check_tiling(&log);
    assert_eq!(lost, 0, "the new acquisition from its first frame, nothing of it lost");
    let d = docs.lock().unwrap();
    use bassclient::bass_result::*;
    let codes: Vec<_> = d.codes.iter().filter(|&&c| c != BASS_ERR_TIMEOUT).copied().collect();
    assert_eq!(codes, [BASS_ERR_RESTARTED], "{:?}", d.codes);
    check_docs_tiling(&d);
    let first_new = d.blocks.iter().find(|b| b.0 == epoch + 1).unwrap();
    assert_eq!((first_new.1, first_new.3), (1, 0), "the docs reader reads the new epoch from frame 1");
}

/// The restart grace in a port file's header (`restart_grace_ms`, at its offset in the one
/// layout definition).
fn grace_in(path: &std::path::Path) -> u32 {
    let bytes = std::fs::read(path).unwrap();
    let at = std::mem::offset_of!(bassport::format::Header, restart_grace_ms);
    u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap())
}

#[test]
fn a_notify_socket_nobody_can_use_gives_no_restart_grace() {
    let dir = TempDir::new("bass-supervised");
    let regular = dir.path().join("regular-file");
    std::fs::write(&regular, b"").unwrap();
    let stream_path = dir.path().join("stream-socket");
    let _listener = std::os::unix::net::UnixListener::bind(&stream_path).unwrap();
    let abstract_name = format!("@bass-test-unbound-{}", std::process::id());
    let targets = [
        dir.path().join("missing").display().to_string(),
        regular.display().to_string(),
        stream_path.display().to_string(),
        abstract_name,
    ];
    for (i, target) in targets.iter().enumerate() {
        let name = format!("nogrc{i}");
        let b = Bassd::builder(dir.path(), &name)
            .args(&ACQUIRE)
            .envs(&[("NOTIFY_SOCKET", target.as_str())])
            .start();
        let port = b.port_once_acquired();
        wait_frame(&port, 1);
        assert_eq!(grace_in(&b.port_path()), 0, "NOTIFY_SOCKET={target}: nothing can take the port back");
        assert!(b.log_text().contains("NOTIFY_SOCKET is not usable"), "{}", b.log_text());
    }
    // A manager that listens keeps the default grace.
    let mut mgr = FakeManager::new(dir.path());
    let b = start(dir.path(), "grc", &mgr, &ACQUIRE, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    acquired(&b);
    assert_eq!(grace_in(&b.port_path()), bassd::supervise::DEFAULT_RESTART_GRACE_MS);
}

/// The handed-back store with its port replaced by `port` (the record kept).
fn with_port(mgr: &FakeManager, port: OwnedFd) -> Vec<(String, OwnedFd)> {
    let mut handed = mgr.handed();
    let slot = handed.iter_mut().find(|(n, _)| n == "bass-port").expect("the store holds the port");
    slot.1 = port;
    handed
}

/// Issue 32 item 11 (a forged fd store, which only the service manager can hand): an
/// unsealed memfd copy of a memfd broker's port is refused by name and the broker runs its
/// `--acquire` (before: taken back as a port file, the broker idle).
#[test]
fn a_forged_store_an_unsealed_copy_of_the_memfd_port_is_refused_and_the_acquire_runs() {
    let dir = TempDir::new("bass-supervised");
    let mut mgr = FakeManager::new(dir.path());
    let mut args = ACQUIRE.to_vec();
    args.extend(["--port-backing", "memfd"]);
    let mut b = start(dir.path(), "forgedcopy", &mgr, &args, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    let epoch = acquired(&b).epoch;
    wait_frame(&open(&b), 1);
    b.signal(libc::SIGKILL);
    b.wait_exit();
    let real = mgr.handed().into_iter().find(|(n, _)| n == "bass-port").unwrap().1;
    let mut real = std::fs::File::from(real);
    let copy = rustix::fs::memfd_create("bass-port:forgedcopy", rustix::fs::MemfdFlags::CLOEXEC).unwrap();
    let mut copy = std::fs::File::from(copy);
    std::io::Seek::seek(&mut real, std::io::SeekFrom::Start(0)).unwrap();
    std::io::copy(&mut real, &mut copy).unwrap();
    let b2 = start(dir.path(), "forgedcopy", &mgr, &args, with_port(&mgr, copy.into()));
    ready(&mut mgr);
    let st = acquired(&b2);
    assert!(st.epoch > epoch, "a new acquisition (epoch {} after {epoch})", st.epoch);
    let log = b2.log_text();
    assert!(log.contains("not this broker's own (an unsealed file"), "{log}");
    let port = open(&b2);
    assert_eq!(port.epoch(), st.epoch);
    wait_frame(&port, 1);
}

/// Issue 32 item 11: a port whose last frame index is 2^62 (at the format's limit) is refused
/// at take-back by name, not taken back to fail at its next publish.
#[test]
fn a_forged_store_a_port_at_frame_2_62_is_refused_at_take_back() {
    let dir = TempDir::new("bass-supervised");
    let mut mgr = FakeManager::new(dir.path());
    let mut b = start(dir.path(), "forgedfar", &mgr, &ACQUIRE, Vec::new());
    ready(&mut mgr);
    stored(&mut mgr);
    let epoch = acquired(&b).epoch;
    wait_frame(&open(&b), 1);
    b.signal(libc::SIGKILL);
    b.wait_exit();
    let at = std::mem::offset_of!(bassport::format::Header, last_frame_index) as u64;
    let f = std::fs::OpenOptions::new().write(true).open(b.port_path()).unwrap();
    std::os::unix::fs::FileExt::write_all_at(&f, &(1u64 << 62).to_le_bytes(), at).unwrap();
    let b2 = start(dir.path(), "forgedfar", &mgr, &ACQUIRE, mgr.handed());
    ready(&mut mgr);
    let st = acquired(&b2);
    assert_eq!(st.epoch, epoch + 1, "a new acquisition; log:\n{}", b2.log_text());
    assert!(b2.log_text().contains("past 9007199254740992"), "{}", b2.log_text());
    let lfi = wait_frame(&open(&b2), 1);
    assert!(lfi < 1 << 40, "the new port starts at its own frame 1 (last frame {lfi})");
}

/// Issue 32 item 11: another (dead) broker's port handed with this broker's record is not
/// taken back (before: written on under this broker's name); the other port is left as it was.
#[test]
fn a_forged_store_another_brokers_port_is_refused_and_left_untouched() {
    let dir = TempDir::new("bass-supervised");
    let other_dir = TempDir::new("bass-supervised-other");
    let mut mgr = FakeManager::new(dir.path());
    let mut other_mgr = FakeManager::new(other_dir.path());
    let mut b = start(dir.path(), "forgedown", &mgr, &ACQUIRE, Vec::new());
    let mut o = start(dir.path(), "forgedother", &other_mgr, &ACQUIRE, Vec::new());
    ready(&mut mgr);
    ready(&mut other_mgr);
    stored(&mut mgr);
    stored(&mut other_mgr);
    let epoch = acquired(&b).epoch;
    wait_frame(&open(&o), 1);
    o.signal(libc::SIGKILL);
    o.wait_exit();
    b.signal(libc::SIGKILL);
    b.wait_exit();
    let before = std::fs::read(o.port_path()).unwrap();
    let theirs = other_mgr.handed().into_iter().find(|(n, _)| n == "bass-port").unwrap().1;
    let b2 = start(dir.path(), "forgedown", &mgr, &ACQUIRE, with_port(&mgr, theirs));
    ready(&mut mgr);
    let st = acquired(&b2);
    assert_eq!(st.epoch, epoch + 1, "a new acquisition; log:\n{}", b2.log_text());
    assert!(b2.log_text().contains("it is not the port file"), "{}", b2.log_text());
    wait_frame(&open(&b2), 1);
    assert_eq!(std::fs::read(o.port_path()).unwrap(), before, "the other broker's port is not written");
}
