use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::sync_channel;
use std::sync::Arc;
use std::time::{Duration, Instant};

use bass_test_support::TempDir;
use basskit::testsignal::{fill_pattern_interleaved, pattern_expected};
use bassport::format::chunk_flags;
use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
use clap::{CommandFactory, Parser};

use super::reader::Reader;
use super::Outgoing;
use crate::mirror::bounds::Bounds;
use crate::mirror::core::{Core, MirrorStatus, Outcome};
use crate::wire;

/// A chunk as received: its header and its samples, planar.
type Got = (wire::Header, Vec<i32>);

/// Runs `Reader::follow` on `port` through a queue of one message; `network` takes the
/// messages (and sets the flag it is given when it has what it wants). Returns the reader's
/// (dropped chunks, lost frames) and what `network` returned.
fn follow<T: Send + 'static>(
    port: &Port,
    network: impl FnOnce(std::sync::mpsc::Receiver<Outgoing>, Arc<AtomicBool>) -> T + Send + 'static,
) -> (u64, u64, T) {
    let term = Arc::new(AtomicBool::new(false));
    let (tx, rx) = sync_channel::<Outgoing>(1);
    let stop = term.clone();
    let network = std::thread::spawn(move || network(rx, stop));
    let matched = AtomicBool::new(true);
    let mut reader = Reader::new("src", &tx, &term, &matched, 7, 1);
    reader.follow(port, &mut |_, _| {}, None).unwrap();
    let (dropped, lost) = (reader.dropped, reader.lost_frames);
    drop(reader);
    drop(tx);
    (dropped, lost, network.join().unwrap())
}

/// What `Reader::follow` sends of a port (nFPC 4, nCOP 16: nFOP 64, 2 channels) that has
/// published `chunks` chunks, through a queue of one message to a slow network (the
/// receiver takes a message every 2 ms), until `want` chunks arrived or 5 s passed.
/// Returns the chunks received and the reader's (dropped chunks, lost frames).
fn follow_a_port(tag: &str, chunks: u64, want: usize) -> (Vec<Got>, u64, u64) {
    let dir = TempDir::shm(tag);
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 4, chunks_on_port: 16 };
    let path = dir.join("bass-src.port");
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "test".into(), group: None }).unwrap();
    let mut s = vec![0; 8];
    for _ in 0..chunks {
        fill_pattern_interleaved(&mut s, 2, w.last_frame_index() + 1);
        w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    }
    let port = Port::open_path(&path).unwrap();
    let (dropped, lost, got) = follow(&port, move |rx, stop| {
        let (mut got, t0) = (Vec::new(), Instant::now());
        while got.len() < want && t0.elapsed() < Duration::from_secs(5) {
            if let Ok(out) = rx.recv_timeout(Duration::from_millis(50)) {
                got.extend(wire::decode_batch(&out.bytes).unwrap().map(|c| (c.header, c.planar())));
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        stop.store(true, Ordering::Relaxed);
        got
    });
    w.remove().unwrap();
    (got, dropped, lost)
}

fn check_chunks(got: &[Got], first: u64) {
    for (k, (h, planar)) in got.iter().enumerate() {
        let f = first + 4 * k as u64;
        assert_eq!(h.first_frame, f, "chunk {k}");
        assert_eq!(h.flags & wire::flags::SOURCE_LOSS, 0, "chunk {k} flagged as after a loss");
        // Planar on the wire: channel 0's four frames, then channel 1's.
        for i in 0..4 {
            let g = f + i as u64;
            assert_eq!(
                [planar[i], planar[4 + i]],
                [pattern_expected(g, 0), pattern_expected(g, 1)],
                "frame {g}"
            );
        }
    }
}

/// Issue 22 item 2: every port chunk flag — LATE included — published at the source arrives
/// with the same flags in the replica, through serve's reader, the wire and the mirror; the
/// replica adds TIME_ESTIMATED (its timestamps are the source's mapped to the local clock,
/// docs/network.md, "Clocks"), and the samples arrive as they were.
#[test]
fn every_source_chunk_flag_late_included_arrives_in_the_replica() {
    let dir = TempDir::shm("flags");
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 32, chunks_on_port: 32 };
    let path = dir.join("bass-src.port");
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "test".into(), group: None }).unwrap();
    // Chunk k carries flags k: every combination of GAP, DISCONTINUITY, TIME_ESTIMATED, LATE.
    let all = chunk_flags::GAP | chunk_flags::DISCONTINUITY | chunk_flags::TIME_ESTIMATED | chunk_flags::LATE;
    assert_eq!(all, 15);
    let mut s = vec![0; 64];
    for flags in 0..=all {
        let meta = ChunkMeta { flags, ..ChunkMeta::default() };
        if flags & chunk_flags::GAP != 0 {
            w.publish(Source::Zeros, meta).unwrap();
        } else {
            fill_pattern_interleaved(&mut s, 2, w.last_frame_index() + 1);
            w.publish(Source::Interleaved(&s), meta).unwrap();
        }
    }
    let port = Port::open_path(&path).unwrap();
    let replica = dir.join("bass-rep.port");
    let st = MirrorStatus { replica: "rep".into(), source: "src".into(), ..Default::default() };
    let core = Core::new(replica.clone(), Bounds::default(), st, 1);
    let (dropped, lost, outcomes) = follow(&port, move |rx, stop| {
        let (mut core, mut outcomes, t0) = (core, Vec::new(), Instant::now());
        while outcomes.len() < 16 && t0.elapsed() < Duration::from_secs(5) {
            if let Ok(out) = rx.recv_timeout(Duration::from_millis(50)) {
                outcomes.extend_from_slice(core.on_message(&out.bytes, 2 + outcomes.len() as u64, None));
            }
        }
        stop.store(true, Ordering::Relaxed);
        (outcomes, core)
    });
    let (outcomes, _core) = outcomes;
    assert_eq!((dropped, lost), (0, 0));
    assert_eq!(outcomes.len(), 16);
    assert!(outcomes.iter().all(|o| matches!(o, Outcome::Applied { gap: 0, .. })), "{outcomes:?}");
    let rep = Port::open_path(&replica).unwrap();
    let (mut l, mut r) = (vec![0; 32], vec![0; 32]);
    for flags in 0..=all {
        let first = 1 + 32 * u64::from(flags);
        let got = rep.chunk_info(first).unwrap().flags;
        assert_eq!(got, flags | chunk_flags::TIME_ESTIMATED, "chunk {flags:#06b}: replica flags {got:#06b}");
        let mut nfr = first;
        let rd = rep.get_audio_data(32, &mut nfr, &mut [&mut l, &mut r]).unwrap();
        assert_eq!((rd.frames, rd.loss), (32, 0));
        for i in 0..32 {
            let g = first + i as u64;
            let want = if flags & chunk_flags::GAP != 0 {
                [0, 0]
            } else {
                [pattern_expected(g, 0), pattern_expected(g, 1)]
            };
            assert_eq!([l[i], r[i]], want, "frame {g}");
        }
    }
    w.remove().unwrap();
}

/// Issue 20 item 5, serve's side: a port that serve (re)opens — after an upstream Acquire,
/// or a serve started on a running port — is sent from its oldest frame still in the
/// window, and that backlog goes through a full queue without a drop.
#[test]
fn a_new_port_is_sent_from_its_oldest_frame_and_its_backlog_is_never_dropped() {
    // 10 chunks published, the window not yet full: frames 1..=40 are all sent.
    let (got, dropped, lost) = follow_a_port("serve-backlog", 10, 10);
    assert_eq!(got.len(), 10, "the backlog of 10 chunks");
    check_chunks(&got, 1);
    assert_eq!((dropped, lost), (0, 0));
    // 30 chunks published: the window holds frames 57..=120, its 16 chunks are sent.
    let (got, dropped, lost) = follow_a_port("serve-midstream", 30, 16);
    assert_eq!(got.len(), 16, "the window's 16 chunks");
    check_chunks(&got, 57);
    assert_eq!((dropped, lost), (0, 0));
}

#[derive(Parser)]
struct Cli {
    #[command(subcommand)]
    cmd: crate::Cmd,
}

/// serve's numeric options; every other option taking a value is text (a name, a path,
/// an endpoint, a choice). A new option must be put in one list or the other.
const NUMERIC: &[(&str, u64, u64)] =
    &[("queue", 1, 16), ("chunks-per-message", 1, 64), ("rt-priority", 0, 99)];
const TEXT: &[&str] = &[
    "name",
    "zenoh-config",
    "mode",
    "listen",
    "connect",
    "namespace",
    "credentials",
    "peer",
    // Identity names, checked against the credentials at start.
    "allow-control",
    // `serve --ros2`: names, checked by crate::ros2::check (its own tests), and an enum.
    "ros2-topic",
    "ros2-node",
    "ros2-frame-id",
    "ros2-distro",
];

fn parse(args: &[&str]) -> Result<Cli, clap::Error> {
    Cli::try_parse_from(["bass-bridge", "serve"].iter().chain(args))
}

/// Issue 20 item 7: inf, NaN, 1e300 and every other number out of range or not whole is
/// a usage error (exit status 2) naming the option, as in `bass`; nothing panics.
#[test]
fn every_numeric_option_refuses_inf_nan_and_out_of_range_values_naming_itself() {
    let cmd = Cli::command();
    let serve = cmd.find_subcommand("serve").expect("serve");
    for arg in serve.get_arguments().filter(|a| a.get_action().takes_values()) {
        let long = arg.get_long().expect("long options only");
        assert!(
            NUMERIC.iter().any(|(n, _, _)| *n == long) || TEXT.contains(&long),
            "--{long}: classify it as NUMERIC (and test it) or TEXT"
        );
    }
    for &(opt, lo, hi) in NUMERIC {
        let flag = format!("--{opt}");
        let below = lo.checked_sub(1).map_or_else(|| "-1".to_string(), |b| b.to_string());
        let above = (hi + 1).to_string();
        for v in
            ["inf", "-inf", "NaN", "1e300", "-1", "1.5", "", "0x10", "18446744073709551616", &below, &above]
        {
            // `--opt=VALUE`: a value starting with '-' is a value, not another option.
            let e = match parse(&[&format!("{flag}={v}")]) {
                Ok(_) => panic!("{flag} {v:?} accepted"),
                Err(e) => e,
            };
            assert_eq!(e.exit_code(), 2, "{flag} {v:?}: {e}");
            assert!(e.to_string().contains(&flag), "{flag} {v:?}: the error names the option: {e}");
        }
        for v in [lo, hi] {
            assert!(parse(&[&flag, &v.to_string()]).is_ok(), "{flag} {v} is accepted");
        }
    }
}

/// What `Reader::follow` sends of a live port (48 kHz, 480-frame chunks every 10 ms, a 1 s
/// window: a live patience of 250 ms) through a queue of one message to a network that takes
/// every message at once but stops taking any for `stall` once 20 chunks arrived. Returns the
/// chunks received until 100 arrived (or 10 s passed) and the reader's (dropped, lost frames).
fn follow_a_live_port(tag: &str, stall: Duration) -> (Vec<Got>, u64, u64) {
    let dir = TempDir::shm(tag);
    let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 480, chunks_on_port: 100 };
    let path = dir.join("bass-src.port");
    let mut w =
        Writer::create_at(&path, &PortParams { geometry, device: "test".into(), group: None }).unwrap();
    let mut s = vec![0; 960];
    fill_pattern_interleaved(&mut s, 2, 1);
    w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
    let port = Port::open_path(&path).unwrap();
    let done = Arc::new(AtomicBool::new(false));
    let writer = {
        let done = done.clone();
        std::thread::spawn(move || {
            let t0 = Instant::now();
            for k in 1u32.. {
                if done.load(Ordering::Relaxed) {
                    break;
                }
                if let Some(d) = (t0 + Duration::from_millis(10) * k).checked_duration_since(Instant::now()) {
                    std::thread::sleep(d);
                }
                fill_pattern_interleaved(&mut s, 2, w.last_frame_index() + 1);
                w.publish(Source::Interleaved(&s), ChunkMeta::default()).unwrap();
            }
            w
        })
    };
    let (dropped, lost, got) = follow(&port, move |rx, stop| {
        let (mut got, t0, mut stalled) = (Vec::<Got>::new(), Instant::now(), false);
        while got.len() < 100 && t0.elapsed() < Duration::from_secs(10) {
            if got.len() >= 20 && !stalled {
                std::thread::sleep(stall);
                stalled = true;
            }
            if let Ok(out) = rx.recv_timeout(Duration::from_millis(50)) {
                got.extend(wire::decode_batch(&out.bytes).unwrap().map(|c| (c.header, c.planar())));
            }
        }
        stop.store(true, Ordering::Relaxed);
        // The queue stays open until the reader has seen `stop`.
        (got, rx)
    });
    let got = got.0;
    done.store(true, Ordering::Relaxed);
    writer.join().unwrap().remove().unwrap();
    (got, dropped, lost)
}

/// Every chunk of `got` has the pattern's samples at its frames (480-frame chunks, planar).
fn check_pattern(got: &[Got]) {
    for (h, planar) in got {
        for i in 0..480 {
            let g = h.first_frame + i as u64;
            assert_eq!(
                [planar[i], planar[480 + i]],
                [pattern_expected(g, 0), pattern_expected(g, 1)],
                "frame {g}"
            );
        }
    }
}

/// A network (or serve's own sender) that takes nothing for 100 ms — less than the live
/// patience of 250 ms — costs no chunk: the port holds the frames meanwhile. (Before, the
/// reader dropped every chunk it found the queue full for: a 50 ms stall of serve lost
/// chunks on a clean link, seen as GAP frames in the replica.)
#[test]
fn a_stall_shorter_than_the_live_patience_loses_nothing() {
    let (got, dropped, lost) = follow_a_live_port("serve-stall", Duration::from_millis(100));
    assert_eq!((dropped, lost), (0, 0), "dropped chunks, lost frames");
    assert_eq!(got.len(), 100);
    for (k, (h, _)) in got.iter().enumerate() {
        assert_eq!(h.first_frame, got[0].0.first_frame + 480 * k as u64, "chunk {k}");
        assert_eq!(h.flags & wire::flags::SOURCE_LOSS, 0, "chunk {k} flagged as after a loss");
    }
    check_pattern(&got);
}

/// A network that takes nothing for 600 ms — longer than the live patience of 250 ms, shorter
/// than the 1 s window — makes serve drop what falls further behind, counted, and the port
/// never laps it: every frame not sent is a dropped chunk's, the chunk after the drops says
/// so, and the chunks received are the pattern at their frames.
#[test]
fn a_stall_longer_than_the_live_patience_drops_counted_and_the_lag_stays_bounded() {
    let (got, dropped, lost) = follow_a_live_port("serve-stall-long", Duration::from_millis(600));
    assert!(dropped > 0, "a 600 ms stall dropped nothing");
    assert_eq!(lost, 480 * dropped, "lost frames are the dropped chunks' (the port never lapped serve)");
    let jumps: Vec<_> = got.windows(2).filter(|p| p[1].0.first_frame != p[0].0.first_frame + 480).collect();
    assert!(!jumps.is_empty(), "no jump in the frames received");
    for p in &jumps {
        assert_ne!(p[1].0.flags & wire::flags::SOURCE_LOSS, 0, "chunk after a drop not flagged");
    }
    let missing: u64 = jumps.iter().map(|p| p[1].0.first_frame - p[0].0.first_frame - 480).sum();
    assert!(missing <= lost, "{missing} frames missing, {lost} counted");
    check_pattern(&got);
}
