//! Multi-process stress: one writer process publishes the pattern signal (every sample
//! encodes its frame and channel) as fast as it can into a small window; five reader
//! processes read it at different speeds, one of them repeatedly SIGSTOPped and SIGCONTed.
//! Every delivered sample is checked. Pass: 0 corrupted samples, and for each reader
//! delivered + lost = frames requested (= every frame published), exactly.
//!
//! The child processes are this test binary re-executed with `BASS_STRESS_ROLE` set.

use bass_test_support::client as common;

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Stdio};
use std::time::Duration;

use basskit::testsignal::fill_pattern_interleaved;
use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};

const CHANNELS: u32 = 2;
const NFPC: u32 = 64;
const NCOP: u32 = 8;
const CHUNKS: u64 = 40_000;

/// Reader kinds: (block size N, pause between reads in µs, use the blocking wait).
const READERS: [(usize, u64, bool); 5] =
    [(64, 0, false), (300, 20, false), (2000, 500, false), (256, 0, true), (128, 0, false)];
/// Index of the reader that gets SIGSTOP / SIGCONT.
const STOPPED_READER: usize = 4;

#[test]
fn readers_at_any_speed_never_see_torn_frames_and_account_every_frame() {
    let path = common::temp_port_path("stress");
    let spawn = |role: &str, arg: &str| -> Child {
        common::child_command("stress_child_entry", "BASS_STRESS_ROLE", role)
            .env("BASS_STRESS_ARG", arg)
            .env("BASS_STRESS_PORT", &path)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn child")
    };
    let mut writer = spawn("writer", "");
    // The writer prints "ready" once the port exists.
    let mut wout = BufReader::new(writer.stdout.take().unwrap());
    let mut line = String::new();
    while !line.contains("ready") {
        line.clear();
        assert!(wout.read_line(&mut line).unwrap() > 0, "writer exited before creating the port");
    }
    let mut readers: Vec<Child> = (0..READERS.len()).map(|k| spawn("reader", &k.to_string())).collect();
    for r in &mut readers {
        let mut out = BufReader::new(r.stdout.as_mut().unwrap());
        let mut l = String::new();
        while !l.contains("ready") {
            l.clear();
            assert!(out.read_line(&mut l).unwrap() > 0, "reader exited before opening the port");
        }
    }
    writer.stdin.as_mut().unwrap().write_all(b"go\n").unwrap();
    let stopped_pid = readers[STOPPED_READER].id() as libc::pid_t;
    let mut stops = 0u32;
    while writer.try_wait().unwrap().is_none() {
        // SAFETY: signalling our own child process.
        unsafe { libc::kill(stopped_pid, libc::SIGSTOP) };
        std::thread::sleep(Duration::from_millis(15));
        // SAFETY: as above.
        unsafe { libc::kill(stopped_pid, libc::SIGCONT) };
        std::thread::sleep(Duration::from_millis(5));
        stops += 1;
    }
    // SAFETY: as above; make sure it is running for the drain.
    unsafe { libc::kill(stopped_pid, libc::SIGCONT) };
    assert!(writer.wait().unwrap().success(), "writer failed");
    let published = CHUNKS * u64::from(NFPC);
    let mut total_checked = 0u64;
    for (k, r) in readers.into_iter().enumerate() {
        let out = r.wait_with_output().unwrap();
        assert!(out.status.success(), "reader {k} failed");
        let text = String::from_utf8_lossy(&out.stdout);
        let result = text.lines().find(|l| l.starts_with("RESULT")).expect("reader result line");
        let field = |name: &str| -> u64 {
            result
                .split_whitespace()
                .find_map(|kv| kv.strip_prefix(&format!("{name}=")))
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("{name} in {result}"))
        };
        let (delivered, lost, corrupted, requested) =
            (field("delivered"), field("lost"), field("corrupted"), field("requested"));
        eprintln!("reader {k} {:?}: {result}", READERS[k]);
        assert_eq!(corrupted, 0, "reader {k} got corrupted samples");
        assert_eq!(requested, published, "reader {k} must have covered every published frame");
        assert_eq!(delivered + lost, requested, "reader {k}: delivered + lost != requested");
        assert!(delivered > 0, "reader {k} delivered nothing");
        total_checked += delivered;
    }
    eprintln!(
        "stress: {published} frames published, {total_checked} frames x {CHANNELS} channels checked, reader {STOPPED_READER} stopped {stops} times"
    );
    std::fs::remove_file(&path).unwrap();
}

/// Child-process entry point (ignored in normal runs; the stress test runs it).
#[test]
#[ignore = "child process of readers_at_any_speed_never_see_torn_frames_and_account_every_frame, which runs it"]
fn stress_child_entry() {
    let role = common::child_entry("BASS_STRESS_ROLE");
    let path = std::path::PathBuf::from(std::env::var("BASS_STRESS_PORT").unwrap());
    match role.as_str() {
        "writer" => run_writer(&path),
        "reader" => run_reader(&path, std::env::var("BASS_STRESS_ARG").unwrap().parse().unwrap()),
        other => panic!("unknown role {other}"),
    }
}

fn run_writer(path: &std::path::Path) {
    let geometry =
        Geometry { channels: CHANNELS, sample_rate: 48000, frames_per_chunk: NFPC, chunks_on_port: NCOP };
    let mut w =
        Writer::create_at(path, &PortParams { geometry, device: "stress".into(), group: None }).unwrap();
    println!("ready");
    let mut go = String::new();
    std::io::stdin().read_line(&mut go).unwrap();
    let mut chunk = vec![0i32; (NFPC * CHANNELS) as usize];
    // Paced at one chunk per 50 µs (about 29x real time at 44.1 kHz) on absolute deadlines,
    // so that readers of every speed interleave with the writer for a few seconds.
    let mut deadline = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: valid out-pointer.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut deadline) };
    for _ in 0..CHUNKS {
        deadline.tv_nsec += 50_000;
        if deadline.tv_nsec >= 1_000_000_000 {
            deadline.tv_nsec -= 1_000_000_000;
            deadline.tv_sec += 1;
        }
        // SAFETY: valid timespec; absolute sleep on CLOCK_MONOTONIC.
        unsafe {
            libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &deadline, std::ptr::null_mut())
        };
        fill_pattern_interleaved(&mut chunk, CHANNELS, w.last_frame_index() + 1);
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).unwrap();
    }
    w.stop();
}

fn run_reader(path: &std::path::Path, kind: usize) {
    let (n, pause_us, blocking) = READERS[kind];
    let port = Port::open_path(path).unwrap();
    println!("ready");
    let nfop = port.frames_on_port() as usize;
    let mut bufs = vec![vec![0i32; n.min(nfop)]; CHANNELS as usize];
    let (mut nfr, start) = (1u64, 1u64);
    let (mut delivered, mut lost, mut corrupted) = (0u64, 0u64, 0u64);
    loop {
        if blocking {
            if let Err(e) = port.wait(nfr + n as u64 - 1, Duration::from_secs(30)) {
                assert!(matches!(e, bassport::Error::Stopped { .. }), "wait: {e}");
            }
        }
        let before = nfr;
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        let r = port.get_audio_data(n, &mut nfr, &mut outs).unwrap();
        corrupted += common::count_not_pattern(before + r.loss, r.frames, &bufs);
        delivered += r.frames as u64;
        lost += r.loss;
        if r.frames == 0 && r.loss == 0 {
            let info = port.info().unwrap();
            if info.state == Some(bassport::State::Stopped) && nfr > info.last_frame_index {
                break;
            }
        }
        if pause_us > 0 {
            std::thread::sleep(Duration::from_micros(pause_us));
        }
    }
    println!("RESULT delivered={delivered} lost={lost} corrupted={corrupted} requested={}", nfr - start);
}
