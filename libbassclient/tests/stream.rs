//! The callback stream (`bassport::stream`): its blocks tile the stream exactly — every
//! frame delivered once, in order, or counted lost — across a lapped slow callback, a skip
//! (frames the writer never had), a device gap, a restart (a new epoch at the same path) and
//! the end of an acquisition, checked sample by sample against the pattern signal.

use bass_test_support::client as common;

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use basskit::testsignal::{fill_pattern_interleaved, pattern_expected};
use bassport::format::{chunk_flags, error_code};
use bassport::stream::{Block, Config, Control, Event, SampleLayout, Start, Stream};
use bassport::{ChunkMeta, Geometry, PortParams, Source, State, Writer};

const NFPC: u32 = 16;
const NCOP: u32 = 8;
const CHANNELS: u32 = 3;

fn params() -> PortParams {
    let geometry =
        Geometry { channels: CHANNELS, sample_rate: 48000, frames_per_chunk: NFPC, chunks_on_port: NCOP };
    PortParams { geometry, device: "stream-test".into(), group: None }
}

/// Publishes one chunk of the pattern signal (frames after the writer's last).
fn publish_pattern(w: &mut Writer, meta: ChunkMeta) {
    let mut chunk = vec![0; (NFPC * CHANNELS) as usize];
    fill_pattern_interleaved(&mut chunk, CHANNELS, w.last_frame_index() + 1);
    w.publish(Source::Interleaved(&chunk), meta).unwrap();
}

/// What the blocks of one epoch must add up to.
#[derive(Default, Debug)]
struct Tiling {
    epoch: u64,
    /// The frame after the last block (the stream's next frame).
    next: u64,
    delivered: u64,
    lost: u64,
    blocks: u64,
    /// Frames (first, last) published as zero GAP chunks in this epoch.
    gaps: Vec<(u64, u64)>,
    flags_seen: u32,
    /// Largest lost count of one block.
    max_lost: u64,
}

impl Tiling {
    fn start(epoch: u64, first: u64) -> Tiling {
        Tiling { epoch, next: first, ..Tiling::default() }
    }

    /// Checks a block against the tiling and the pattern, sample by sample.
    fn check(&mut self, b: &Block<'_>) {
        assert_eq!(b.epoch, self.epoch, "a block of another epoch");
        assert_eq!(
            b.first_frame,
            self.next + b.lost,
            "block at {} after {} + lost {}",
            b.first_frame,
            self.next,
            b.lost
        );
        assert!(b.frames > 0);
        for i in 0..b.frames {
            let f = b.first_frame + i as u64;
            let in_gap = self.gaps.iter().any(|&(a, z)| (a..=z).contains(&f));
            for (k, &c) in b.channels().iter().enumerate() {
                let want = if in_gap { 0 } else { pattern_expected(f, c) };
                assert_eq!(b.sample(k, i), want, "frame {f} channel {c}");
            }
            if in_gap {
                assert!(
                    b.flags & chunk_flags::GAP != 0,
                    "frame {f} is in a gap but the block has no GAP flag"
                );
            }
        }
        match b.channel(0) {
            Some(s) => assert_eq!(s.len(), b.frames),
            None => assert_eq!(b.interleaved().unwrap().len(), b.frames * b.channels().len()),
        }
        assert!(b.mono_ns > 0 && b.realtime_ns > 0 && b.rate_hz == 48000.0);
        self.next = b.first_frame + b.frames as u64;
        self.delivered += b.frames as u64;
        self.lost += b.lost;
        self.max_lost = self.max_lost.max(b.lost);
        self.blocks += 1;
        self.flags_seen |= b.flags;
    }
}

struct Script {
    w: Option<Writer>,
    path: std::path::PathBuf,
    epochs: Vec<Tiling>,
    events: Vec<String>,
    calls: u64,
}

/// One scripted run, the callback driving the writer (no second thread: every loss is
/// deterministic). Returns the per-epoch tilings and the events.
fn scripted(cfg: Config) -> (Vec<Tiling>, Vec<String>) {
    let path = common::temp_port_path("stream-script");
    let mut w = Writer::create_at(&path, &params()).unwrap();
    for _ in 0..3 {
        publish_pattern(&mut w, ChunkMeta::default());
    }
    let mut stream = Stream::open_path(&path, cfg).unwrap();
    let first = 1; // both configurations start at frame 1 (the oldest here)
    let epoch = w.epoch();
    let s = Rc::new(RefCell::new(Script {
        w: Some(w),
        path: path.clone(),
        epochs: vec![Tiling::start(epoch, first)],
        events: Vec::new(),
        calls: 0,
    }));
    let (sb, se) = (s.clone(), s.clone());
    stream
        .run(
            move |b| {
                let mut s = sb.borrow_mut();
                s.calls += 1;
                s.epochs.last_mut().unwrap().check(b);
                let n = s.calls;
                let w = s.w.as_mut().unwrap();
                match n {
                    // A slow callback: the writer laps it by more than the window.
                    10 | 40 => (0..NCOP * 2 + 3).for_each(|_| publish_pattern(w, ChunkMeta::default())),
                    // Frames the writer never had (an upstream loss): they are lost.
                    15 => {
                        let lfi = w.last_frame_index();
                        w.skip_to(lfi + 1 + 3 * u64::from(NFPC)).unwrap();
                        publish_pattern(w, ChunkMeta::default());
                    }
                    // A device gap: zero frames flagged GAP, delivered like any other frame.
                    20 => {
                        let first = w.last_frame_index() + 1;
                        let gap = ChunkMeta { flags: chunk_flags::GAP, ..ChunkMeta::default() };
                        w.publish(Source::Zeros, gap).unwrap();
                        let last = w.last_frame_index();
                        s.epochs.last_mut().unwrap().gaps.push((first, last));
                        let w = s.w.as_mut().unwrap();
                        let disc = ChunkMeta { flags: chunk_flags::DISCONTINUITY, ..ChunkMeta::default() };
                        publish_pattern(w, disc);
                    }
                    // A new acquisition at the same path (a new epoch).
                    30 => {
                        publish_pattern(w, ChunkMeta::default());
                        let path = s.path.clone();
                        let mut nw = Writer::create_at(&path, &params()).unwrap();
                        publish_pattern(&mut nw, ChunkMeta::default());
                        publish_pattern(&mut nw, ChunkMeta::default());
                        let old = s.w.replace(nw).unwrap();
                        drop(old);
                    }
                    61.. => {} // stopped: the stream drains what is left
                    60 => {
                        publish_pattern(w, ChunkMeta::default());
                        w.stop();
                    }
                    // Keep at least one more block published (the callback is the only writer).
                    _ if b.epoch == w.epoch() => {
                        let due = b.first_frame + 2 * b.frames as u64;
                        while w.last_frame_index() < due {
                            publish_pattern(w, ChunkMeta::default());
                        }
                    }
                    _ => publish_pattern(w, ChunkMeta::default()),
                }
                Control::Continue
            },
            move |e| {
                let mut s = se.borrow_mut();
                s.events.push(format!("{e:?}"));
                match *e {
                    Event::Restarted { epoch, resume_at } => {
                        s.epochs.push(Tiling::start(epoch, resume_at));
                        Control::Continue
                    }
                    Event::Stopped { last } => {
                        let t = s.epochs.last().unwrap();
                        assert_eq!(t.next, last + 1, "the stream ends after the last frame");
                        Control::Stop
                    }
                    _ => Control::Stop,
                }
            },
        )
        .unwrap();
    drop(stream);
    let s = Rc::try_unwrap(s).ok().expect("the closures are gone").into_inner();
    s.w.unwrap().remove().unwrap();
    (s.epochs, s.events)
}

fn check_scripted(cfg: Config, first: u64) {
    let (epochs, events) = scripted(cfg.clone());
    assert_eq!(events.len(), 2, "{events:?}");
    assert!(events[0].starts_with("Restarted"), "{events:?}");
    assert!(events[1].starts_with("Stopped"), "{events:?}");
    assert_eq!(epochs.len(), 2);
    let (a, b) = (&epochs[0], &epochs[1]);
    // Every frame from the first one to the last is delivered once or counted lost.
    assert_eq!(first + a.delivered + a.lost, a.next, "{a:?}");
    // A lap loses more than a window at once (19 chunks published while the callback ran).
    assert!(a.max_lost.max(b.max_lost) > u64::from(NFPC * NCOP), "{a:?} {b:?}");
    assert!(a.flags_seen & chunk_flags::GAP != 0 && a.flags_seen & chunk_flags::DISCONTINUITY != 0);
    assert_eq!(b.epoch, a.epoch + 1);
    assert_eq!(1 + b.delivered + b.lost, b.next, "{b:?}");
    assert!(a.lost > 0 && b.lost > 0, "a lap or a skip in each epoch: {a:?} {b:?}");
    assert!(a.blocks + b.blocks > 60);
}

#[test]
fn planar_blocks_tile_the_stream_across_laps_a_skip_a_gap_and_a_restart() {
    check_scripted(Config::default().oldest(), 1);
}

#[test]
fn interleaved_blocks_of_a_channel_subset_tile_the_stream() {
    let cfg = Config {
        channels: vec![2, 0],
        layout: SampleLayout::Interleaved,
        frames_per_call: 24, // not a whole number of chunks: blocks straddle chunks
        start: Start::Frame(1),
        realtime_priority: None,
    };
    check_scripted(cfg, 1);
}

#[test]
fn a_start_frame_already_gone_is_counted_lost_before_the_first_block() {
    let path = common::temp_port_path("stream-start");
    let mut w = Writer::create_at(&path, &params()).unwrap();
    for _ in 0..NCOP + 2 {
        publish_pattern(&mut w, ChunkMeta::default());
    }
    w.stop();
    let mut firsts = Vec::new();
    let cfg = Config { start: Start::Frame(5), ..Config::default() };
    let mut stream = Stream::open_path(&path, cfg).unwrap();
    stream
        .run(
            |b| {
                firsts.push((b.first_frame, b.lost));
                Control::Continue
            },
            |_| Control::Stop,
        )
        .unwrap();
    let oldest = u64::from(NFPC * 2) + 1;
    assert_eq!(firsts[0], (oldest, oldest - 5));
    assert_eq!(firsts.len(), NCOP as usize);
    let mut now = Stream::open_path(&path, Config::default()).unwrap();
    let mut n = 0;
    now.run(
        |_| {
            n += 1;
            Control::Continue
        },
        |_| Control::Stop,
    )
    .unwrap();
    assert_eq!(n, 0, "a stream from the live edge of a stopped port delivers nothing");
    w.remove().unwrap();
}

#[test]
fn a_device_error_ends_with_its_code_and_message_after_the_last_frames() {
    let path = common::temp_port_path("stream-device");
    let mut w = Writer::create_at(&path, &params()).unwrap();
    for _ in 0..2 {
        publish_pattern(&mut w, ChunkMeta::default());
    }
    w.set_state(State::Error, error_code::DEVICE_LOST, "hw:1 unplugged");
    let mut stream =
        Stream::open_path(&path, Config { frames_per_call: 20, ..Config::default().oldest() }).unwrap();
    let mut blocks = Vec::new();
    let mut events = Vec::new();
    stream
        .run(
            |b| {
                blocks.push((b.first_frame, b.frames));
                Control::Continue
            },
            |e| {
                events.push(format!("{e:?}"));
                Control::Stop
            },
        )
        .unwrap();
    assert_eq!(blocks, [(1, 20), (21, 12)], "the frames before the error, the last block partial");
    assert_eq!(
        events,
        [format!("{:?}", Event::Device { code: error_code::DEVICE_LOST, message: "hw:1 unplugged" })]
    );
    w.remove().unwrap();
}

#[test]
fn a_stopped_stream_that_continues_follows_the_next_acquisition() {
    let path = common::temp_port_path("stream-follow");
    let mut w = Writer::create_at(&path, &params()).unwrap();
    publish_pattern(&mut w, ChunkMeta::default());
    w.stop();
    let mut stream = Stream::open_path(&path, Config::default().oldest()).unwrap();
    let stopper = stream.stopper();
    let p = path.clone();
    let restarter = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(20));
        let mut nw = Writer::create_at(&p, &params()).unwrap();
        publish_pattern(&mut nw, ChunkMeta::default());
        nw
    });
    let mut seen = Vec::new();
    let mut events = Vec::new();
    stream
        .run(
            |b| {
                seen.push((b.epoch, b.first_frame));
                if b.epoch == 2 {
                    stopper.stop(); // a stop from inside the callback
                }
                Control::Continue
            },
            |e| {
                events.push(format!("{e:?}"));
                Control::Continue
            },
        )
        .unwrap();
    assert_eq!(seen, [(1, 1), (2, 1)]);
    assert_eq!(events, ["Stopped { last: 16 }", "Restarted { epoch: 2, resume_at: 1 }"]);
    restarter.join().unwrap().remove().unwrap();
    drop(w);
}

/// Two threads: a writer publishing in bursts and a spawned stream whose callback is now and
/// then slow, so the writer laps it at random points, also while it copies.
#[test]
fn a_spawned_stream_tiles_a_concurrent_writer_with_a_slow_callback() {
    let path = common::temp_port_path("stream-threads");
    let mut w = Writer::create_at(&path, &params()).unwrap();
    let stream =
        Stream::open_path(&path, Config { frames_per_call: 40, ..Config::default().oldest() }).unwrap();
    let tiling = Arc::new(Mutex::new(Tiling::start(w.epoch(), 1)));
    let ended = Arc::new(AtomicU64::new(0));
    let (t, e) = (tiling.clone(), ended.clone());
    let mut rng = fastrand::Rng::with_seed(25);
    let handle = stream
        .spawn(
            move |b| {
                t.lock().unwrap().check(b);
                if b.first_frame % 7 == 0 {
                    std::thread::sleep(Duration::from_micros(300));
                }
                Control::Continue
            },
            move |ev| {
                if let Event::Stopped { last } = *ev {
                    e.store(last, Ordering::SeqCst);
                }
                Control::Stop
            },
        )
        .unwrap();
    for i in 0..4000 {
        publish_pattern(&mut w, ChunkMeta::default());
        if i % 50 == 0 {
            std::thread::sleep(Duration::from_micros(rng.u64(0..500)));
        }
    }
    w.stop();
    let (_stream, r) = handle.join();
    r.unwrap();
    let t = tiling.lock().unwrap();
    let last = ended.load(Ordering::SeqCst);
    assert_eq!(last, 4000 * u64::from(NFPC));
    assert_eq!(1 + t.delivered + t.lost, last + 1, "{t:?}");
    assert_eq!(t.next, last + 1);
    assert!(t.blocks > 100, "{t:?}");
    w.remove().unwrap();
}

#[test]
fn a_handle_stops_a_waiting_stream_and_a_bad_config_is_refused() {
    let path = common::temp_port_path("stream-stop");
    let w = Writer::create_at(&path, &params()).unwrap();
    let handle = Stream::open_path(&path, Config::default())
        .unwrap()
        .spawn(|_| Control::Continue, |_| Control::Continue)
        .unwrap();
    handle.stop();
    let (stream, r) = handle.join();
    r.unwrap();
    assert_eq!(stream.next_frame(), Some(1));
    let too_long = Config { frames_per_call: (NFPC * NCOP + 1) as usize, ..Config::default() };
    assert!(Stream::open_path(&path, too_long).is_err());
    let no_channel = Config { channels: vec![CHANNELS], ..Config::default() };
    assert!(Stream::open_path(&path, no_channel).is_err());
    w.remove().unwrap();
}

/// The C exports refuse forged and closed handles and NULL arguments with their codes.
#[test]
fn the_c_exports_refuse_forged_handles_and_null_arguments() {
    use bassclient::*;
    let forged = 0x1230usize as *mut bass_stream;
    // SAFETY: the exports take any handle value (registry keys, never dereferenced).
    unsafe {
        assert_eq!(bass_stream_stop(forged), bass_result::BASS_ERR_INVALID_HANDLE);
        assert_eq!(bass_stream_run(forged), bass_result::BASS_ERR_INVALID_HANDLE);
        assert_eq!(bass_stream_close(forged), bass_result::BASS_ERR_INVALID_HANDLE);
        assert_eq!(bass_stream_close(std::ptr::null_mut()), bass_result::BASS_OK);
        assert_eq!(bass_stream_stop(std::ptr::null_mut()), bass_result::BASS_ERR_NULL_ARGUMENT);
        let cfg = bass_stream_config {
            frames_per_call: 0,
            start: BASS_START_NOW,
            interleaved: 0,
            start_frame: 0,
            channels: std::ptr::null(),
            n_channels: 0,
            realtime_priority: 0,
        };
        unsafe extern "C" fn on_block(_: *const bass_block, _: *mut std::ffi::c_void) -> std::ffi::c_int {
            1
        }
        let mut out = std::ptr::null_mut();
        let forged_port = 0x4560usize as *const bass_port;
        let r = bass_stream_start(forged_port, &cfg, Some(on_block), None, std::ptr::null_mut(), &mut out);
        assert_eq!(r, bass_result::BASS_ERR_INVALID_HANDLE);
        assert!(out.is_null(), "no output on failure");
    }
}

/// A stream made from a port opened by name finds the next acquisition by that name (the
/// way a broker's port is found again, also a memfd one) and resumes at its first frame.
#[test]
fn a_stream_over_a_port_opened_by_name_follows_a_restart_by_name() {
    let dir = common::temp_port_path("stream-named-dir");
    std::fs::create_dir_all(&dir).unwrap();
    // Only this test opens ports by name; the others give paths.
    std::env::set_var("BASS_RUNTIME_DIR", &dir);
    let mut w = Writer::create("named", &params()).unwrap();
    publish_pattern(&mut w, ChunkMeta::default());
    let port = Arc::new(bassport::Port::open("named").unwrap());
    let mut stream = Stream::new(port, Config::default().oldest()).unwrap();
    let mut next = Some(w);
    let mut kept = None;
    let mut seen = Vec::new();
    stream
        .run(
            |b| {
                seen.push((b.epoch, b.first_frame, b.sample(0, 0)));
                if let Some(old) = next.take() {
                    let mut nw = Writer::create("named", &params()).unwrap();
                    publish_pattern(&mut nw, ChunkMeta::default());
                    drop(old);
                    nw.stop();
                    kept = Some(nw);
                }
                Control::Continue
            },
            |e| if matches!(e, Event::Restarted { .. }) { Control::Continue } else { Control::Stop },
        )
        .unwrap();
    assert_eq!(seen, [(1, 1, pattern_expected(1, 0)), (2, 1, pattern_expected(1, 0))]);
    kept.expect("the second acquisition").remove().unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A realtime priority is applied to the stream's thread, or its refusal reported with the
/// errno, and the stream runs either way.
#[test]
fn a_refused_realtime_priority_is_reported_and_the_stream_goes_on() {
    let path = common::temp_port_path("stream-fifo");
    let mut w = Writer::create_at(&path, &params()).unwrap();
    for _ in 0..2 {
        publish_pattern(&mut w, ChunkMeta::default());
    }
    w.stop();
    // 10: granted (root, rtprio limit) or refused; 1000: out of SCHED_FIFO's range, refused.
    for (priority, must_refuse) in [(10, false), (1000, true)] {
        let cfg = Config { realtime_priority: Some(priority), ..Config::default().oldest() };
        let events = Arc::new(Mutex::new(Vec::new()));
        let blocks = Arc::new(AtomicU64::new(0));
        let (e, b) = (events.clone(), blocks.clone());
        let handle = Stream::open_path(&path, cfg)
            .unwrap()
            .spawn(
                move |_| {
                    b.fetch_add(1, Ordering::SeqCst);
                    Control::Continue
                },
                move |ev| {
                    e.lock().unwrap().push(format!("{ev:?}"));
                    if matches!(ev, Event::RealtimeRefused { .. }) {
                        Control::Continue
                    } else {
                        Control::Stop
                    }
                },
            )
            .unwrap();
        let (_, r) = handle.join();
        r.unwrap();
        assert_eq!(blocks.load(Ordering::SeqCst), 2);
        let events = events.lock().unwrap();
        let refused = events.len() == 2
            && events[0].starts_with("RealtimeRefused { errno: ")
            && events[0] != "RealtimeRefused { errno: 0 }";
        assert!(refused || (events.len() == 1 && !must_refuse), "{events:?}");
        if must_refuse {
            assert_eq!(events[0], format!("RealtimeRefused {{ errno: {} }}", libc::EINVAL));
        }
        assert_eq!(events.last().unwrap(), "Stopped { last: 32 }");
    }
    w.remove().unwrap();
}

/// What the C-ABI stream tests' callbacks record.
#[derive(Default)]
struct CSeen {
    blocks: u64,
    /// (kind, epoch, frame) of every event.
    events: Vec<(u32, u64, u64)>,
}

unsafe extern "C" fn c_on_block(
    _: *const bassclient::bass_block,
    user: *mut std::ffi::c_void,
) -> std::ffi::c_int {
    // SAFETY: `user` is the test's `CSeen`, alive and used by this stream's thread only.
    unsafe { (*user.cast::<CSeen>()).blocks += 1 };
    0
}

unsafe extern "C" fn c_on_event(
    e: *const bassclient::bass_stream_event,
    user: *mut std::ffi::c_void,
) -> std::ffi::c_int {
    // SAFETY: the library passes a valid event; `user` is the test's `CSeen`.
    let (e, seen) = unsafe { (&*e, &mut *user.cast::<CSeen>()) };
    seen.events.push((e.kind, e.epoch, e.frame));
    // Go on after a refused priority; end at the end of the acquisition.
    std::ffi::c_int::from(e.kind != bassclient::BASS_EVENT_REALTIME_REFUSED)
}

/// A C-ABI stream from the oldest frame over the port file at `path` (run on this thread).
fn c_stream_run(
    path: &std::path::Path,
    priority: i32,
    on_event: bassclient::bass_event_fn,
    seen: &mut CSeen,
) {
    use bassclient::*;
    let cpath = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    let cfg = bass_stream_config {
        frames_per_call: 0,
        start: BASS_START_OLDEST,
        interleaved: 0,
        start_frame: 0,
        channels: std::ptr::null(),
        n_channels: 0,
        realtime_priority: priority,
    };
    let (mut port, mut s) = (std::ptr::null_mut(), std::ptr::null_mut());
    // SAFETY: valid C string, config and out-pointers; `seen` outlives the stream (closed here).
    unsafe {
        assert_eq!(bass_port_open_path(cpath.as_ptr(), &mut port), bass_result::BASS_OK);
        let user = (seen as *mut CSeen).cast();
        assert_eq!(
            bass_stream_create(port, &cfg, Some(c_on_block), on_event, user, &mut s),
            bass_result::BASS_OK
        );
        assert_eq!(bass_port_close(port), bass_result::BASS_OK);
        assert_eq!(bass_stream_run(s), bass_result::BASS_OK);
        assert_eq!(bass_stream_close(s), bass_result::BASS_OK);
    }
}

/// Events carry the stream's epoch from the first one on (not 0 before a restart).
#[test]
fn c_events_carry_the_ports_epoch_before_any_restart() {
    let path = common::temp_port_path("stream-c-epoch");
    drop(Writer::create_at(&path, &params()).unwrap()); // epoch 1, stopped
    let mut w = Writer::create_at(&path, &params()).unwrap();
    assert_eq!(w.epoch(), 2);
    for _ in 0..2 {
        publish_pattern(&mut w, ChunkMeta::default());
    }
    w.stop();
    let mut seen = CSeen::default();
    // Priority 1000 is out of SCHED_FIFO's range: always refused (EINVAL).
    c_stream_run(&path, 1000, Some(c_on_event), &mut seen);
    use bassclient::*;
    assert_eq!(
        seen.events,
        [(BASS_EVENT_REALTIME_REFUSED, 2, 0), (BASS_EVENT_STOPPED, 2, 2 * u64::from(NFPC))]
    );
    assert_eq!(seen.blocks, 2);
    w.remove().unwrap();
}

/// A refused realtime priority is no end of the stream, with or without an event callback;
/// `bass_stream_run` gives the caller's thread its scheduling back.
#[test]
fn a_refused_priority_goes_on_without_an_event_callback_and_run_restores_the_scheduling() {
    let path = common::temp_port_path("stream-c-fifo");
    let mut w = Writer::create_at(&path, &params()).unwrap();
    for _ in 0..2 {
        publish_pattern(&mut w, ChunkMeta::default());
    }
    w.stop();
    let mut seen = CSeen::default();
    c_stream_run(&path, 1000, None, &mut seen);
    assert_eq!(seen.blocks, 2, "refused, the stream goes on unprioritised (and ends at the stop)");
    // Priority 10: granted where the limits allow it, and given back after the run.
    // SAFETY: no pointers; pid 0 is this thread.
    let before = unsafe { libc::sched_getscheduler(0) };
    let mut seen = CSeen::default();
    c_stream_run(&path, 10, Some(c_on_event), &mut seen);
    // SAFETY: as above.
    let after = unsafe { libc::sched_getscheduler(0) };
    assert_eq!(after, before, "the caller's thread keeps its own scheduling after bass_stream_run");
    assert_eq!(seen.blocks, 2);
    w.remove().unwrap();
}

/// A stream that waits after a device error follows the same acquisition when a successor
/// takes the port back (`Writer::resume`): one Resumed, in the same epoch, at the frame after
/// the last block; the frames missed meanwhile arrive as GAP, and the blocks tile on.
#[test]
fn a_stream_that_waits_after_a_device_error_follows_the_resume_of_its_acquisition() {
    let path = common::temp_port_path("stream-resume");
    let mut w = Writer::create_at(&path, &params()).unwrap();
    for _ in 0..2 {
        publish_pattern(&mut w, ChunkMeta::default());
    }
    w.set_state(State::Error, error_code::DEVICE_LOST, "hw:1 unplugged");
    let mut stream =
        Stream::open_path(&path, Config { frames_per_call: 20, ..Config::default().oldest() }).unwrap();
    let mut successor: Option<Writer> = None;
    let tiling = RefCell::new(Tiling::start(1, 1));
    let mut events = Vec::new();
    let (blocks, resumed) = (RefCell::new(0u32), RefCell::new(false));
    let path2 = path.clone();
    stream
        .run(
            |b| {
                tiling.borrow_mut().check(b);
                *blocks.borrow_mut() += 1;
                Control::Continue
            },
            |e| {
                events.push(format!("{e:?}"));
                match e {
                    Event::Device { .. } if !*resumed.borrow() => {
                        // The successor: takes the port back, the missed frames as a GAP chunk.
                        let file = std::fs::OpenOptions::new().read(true).write(true).open(&path2).unwrap();
                        let mut w2 = Writer::resume(file, &path2).unwrap();
                        let first = w2.last_frame_index() + 1;
                        let gap = ChunkMeta { flags: chunk_flags::GAP, ..ChunkMeta::default() };
                        w2.publish(Source::Zeros, gap).unwrap();
                        tiling.borrow_mut().gaps.push((first, w2.last_frame_index()));
                        for _ in 0..2 {
                            publish_pattern(&mut w2, ChunkMeta::default());
                        }
                        w2.stop();
                        successor = Some(w2);
                        *resumed.borrow_mut() = true;
                        Control::Continue
                    }
                    Event::Resumed { .. } => Control::Continue,
                    _ => Control::Stop,
                }
            },
        )
        .unwrap();
    let device = format!("{:?}", Event::Device { code: error_code::DEVICE_LOST, message: "hw:1 unplugged" });
    let last = 5 * u64::from(NFPC);
    assert_eq!(
        events,
        [device, "Resumed { epoch: 1, resume_at: 33 }".to_owned(), format!("Stopped {{ last: {last} }}")]
    );
    let tiling = tiling.into_inner();
    assert_eq!((tiling.next, tiling.delivered, tiling.lost), (last + 1, last, 0));
    assert!(tiling.flags_seen & chunk_flags::GAP != 0);
    drop(w);
    successor.unwrap().remove().unwrap();
}

/// Issue 32 item 9: a run whose block callback panics, caught by the caller, and a second
/// run: the block the panicking callback saw is not delivered again (no frame twice with
/// `lost = 0`), and the second run goes on at the frame after it.
#[test]
fn a_run_after_a_caught_panic_goes_on_after_the_block_the_callback_saw() {
    let path = common::temp_port_path("stream-panic");
    let mut w = Writer::create_at(&path, &params()).unwrap();
    for _ in 0..4 {
        publish_pattern(&mut w, ChunkMeta::default());
    }
    w.stop();
    let cfg = Config { start: Start::Oldest, ..Config::default() };
    let mut stream = Stream::open_path(&path, cfg).unwrap();
    let mut seen: Vec<(u64, usize, u64)> = Vec::new();
    let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        stream.run(
            |b| {
                seen.push((b.first_frame, b.frames, b.lost));
                if seen.len() == 2 {
                    panic!("the callback fails at its second block");
                }
                Control::Continue
            },
            |_| Control::Stop,
        )
    }));
    assert!(caught.is_err(), "the panic reaches the caller");
    assert_eq!(seen.len(), 2);
    let after_panic = seen[1].0 + seen[1].1 as u64;
    assert_eq!(stream.next_frame(), Some(after_panic));
    let mut again: Vec<(u64, usize, u64)> = Vec::new();
    stream
        .run(
            |b| {
                again.push((b.first_frame, b.frames, b.lost));
                Control::Continue
            },
            |_| Control::Stop,
        )
        .unwrap();
    assert_eq!(again.first().map(|b| (b.0, b.2)), Some((after_panic, 0)), "re-delivered: {again:?}");
    let total: usize = seen.iter().chain(&again).map(|b| b.1).sum();
    assert_eq!(total as u64, 4 * u64::from(NFPC), "every frame once");
    w.remove().unwrap();
}
