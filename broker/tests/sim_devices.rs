//! The simulated devices through a real bassd and the port: exact contents, frame indices,
//! timestamps, overrun gap filling, the stall watchdog and device loss.

use bass_test_support::*;
use basskit::testsignal::pattern_sample;
use bassport::format::{chunk_flags, error_code, State};
use bassport::Error;

#[test]
fn pattern_frames_arrive_exactly_with_nominal_timestamps() {
    let dir = TempDir::new("pattern");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let a = b.client().acquire(&acquire_req("sim:pattern", 48000, 480, 50, 2)).unwrap();
    assert_eq!((a.epoch, a.format.as_str()), (1, "S32_LE"));
    let port = b.port();
    assert_eq!(port.epoch(), 1);
    wait_frame(&port, 4800);
    let data = read_frames(&port, 1, 4800);
    for (c, chan) in data.iter().enumerate() {
        for (i, &s) in chan.iter().enumerate() {
            assert_eq!(s, pattern_sample(i as u64 + 1, c as u32), "frame {} channel {c}", i + 1);
        }
    }
    // Chunk k starts at frame 480k+1, exactly 10 ms of device time after chunk k-1.
    let first = port.chunk_info(1).unwrap();
    for k in 1..10u64 {
        let ci = port.chunk_info(480 * k + 1).unwrap();
        assert_eq!(ci.first_frame, 480 * k + 1);
        assert_eq!(ci.frames, 480);
        // (LATE may mark a chunk whose read a loaded machine delayed by more than 10 ms.)
        assert_eq!(ci.flags & !chunk_flags::LATE, 0);
        assert_eq!(ci.mono_ns - first.mono_ns, k * 10_000_000, "chunk {k}");
        assert!(ci.realtime_ns > 0);
    }
    let info = port.info().unwrap();
    assert_eq!(info.state, Some(State::Capturing));
    assert_eq!((info.xruns, info.gap_frames), (0, 0));
}

#[test]
fn any_rate_chunk_size_and_channel_count_is_accepted() {
    let dir = TempDir::new("geometry");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    for (rate, nfpc, ncop, ch) in [(8000, 100, 7, 1), (11025, 37, 3, 5), (96000, 960, 4, 2)] {
        c.acquire(&acquire_req("sim:pattern", rate, nfpc, ncop, ch)).unwrap();
        let port = b.port();
        let g = port.geometry().clone();
        assert_eq!((g.sample_rate, g.frames_per_chunk, g.chunks_on_port, g.channels), (rate, nfpc, ncop, ch));
        let last = u64::from(nfpc) * 2;
        wait_frame(&port, last);
        let data = read_frames(&port, 1, last);
        assert_eq!(data.len(), ch as usize);
        for (c, chan) in data.iter().enumerate() {
            for (i, &s) in chan.iter().enumerate() {
                assert_eq!(s, pattern_sample(i as u64 + 1, c as u32));
            }
        }
    }
}

#[test]
fn sine_device_has_distinct_tones_on_left_and_right() {
    let dir = TempDir::new("sine");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:sine", 48000, 4800, 10, 2)).unwrap();
    let port = b.port();
    wait_frame(&port, 4800);
    let d = read_frames(&port, 1, 4800);
    // Count sign changes: 440 Hz and 660 Hz give 88 and 132 zero crossings in 0.1 s.
    let crossings = |v: &[i32]| v.windows(2).filter(|w| (w[0] < 0) != (w[1] < 0)).count();
    assert!((87..=89).contains(&crossings(&d[0])), "left: {}", crossings(&d[0]));
    assert!((131..=133).contains(&crossings(&d[1])), "right: {}", crossings(&d[1]));
    let peak = d[0].iter().map(|s| s.unsigned_abs()).max().unwrap();
    assert!(peak > (1 << 30) - (1 << 20) && peak <= 1 << 30, "peak {peak}");
}

#[test]
fn overruns_are_zero_filled_so_frame_index_stays_proportional_to_time() {
    // sim:xrun at 8000 Hz loses 8000/20 + 7 = 407 frames after every 4000 delivered frames.
    let dir = TempDir::new("xrun");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:xrun", 8000, 100, 100, 2)).unwrap();
    let port = b.port();
    wait_frame(&port, 9000);
    let d = read_frames(&port, 1, 9000);
    let is_gap = |f: u64| (4001..=4407).contains(&f) || (8408..=8814).contains(&f);
    for f in 1..=9000u64 {
        for c in 0..2u32 {
            let want = if is_gap(f) { 0 } else { pattern_sample(f, c) };
            assert_eq!(d[c as usize][f as usize - 1], want, "frame {f} channel {c}");
        }
    }
    let info = port.info().unwrap();
    assert!(info.xruns >= 2, "xruns {}", info.xruns);
    assert!(info.gap_frames >= 814 && info.gap_frames % 407 == 0, "gap frames {}", info.gap_frames);
    // Chunks 4001..4100 .. 4301..4400 are all zeros; 4401..4500 mixes zeros and data.
    let gap = port.chunk_info(4001).unwrap();
    assert_eq!(gap.flags & chunk_flags::GAP, chunk_flags::GAP);
    assert_eq!(port.chunk_info(4301).unwrap().flags & chunk_flags::GAP, chunk_flags::GAP);
    let mixed = port.chunk_info(4401).unwrap();
    assert_eq!(mixed.flags & (chunk_flags::GAP | chunk_flags::DISCONTINUITY), chunk_flags::DISCONTINUITY);
    // Timestamps stay on the device clock across the gap: chunk 45 starts 4400 frames after chunk 1.
    let first = port.chunk_info(1).unwrap();
    assert_eq!(mixed.mono_ns - first.mono_ns, 4400 * 1_000_000_000 / 8000);
    assert_eq!(port.chunk_info(4501).unwrap().mono_ns - first.mono_ns, 4500 * 1_000_000_000 / 8000);
}

#[test]
fn a_stalled_device_ends_in_error_for_a_waiting_reader_and_a_new_acquire_works() {
    let dir = TempDir::new("stall");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let mut c = b.client();
    c.acquire(&acquire_req("sim:stall", 8000, 100, 100, 2)).unwrap();
    let port = b.port();
    // The device delivers 4000 frames, then nothing: the waiting reader is woken with an error.
    match port.wait(1_000_000, PATIENCE) {
        Err(Error::Device { code, message }) => {
            assert_eq!(code, error_code::DEVICE_STALLED);
            assert!(message.contains("device stalled: no data for"), "{message}");
        }
        other => panic!("expected a device error, got {other:?}"),
    }
    let info = port.info().unwrap();
    assert_eq!(info.last_frame_index, 4000);
    let d = read_frames(&port, 3901, 4000);
    assert_eq!(d[1][99], pattern_sample(4000, 1));
    let s = c.status().unwrap();
    assert_eq!((s.state, s.error_code), (State::Error as u32, error_code::DEVICE_STALLED));
    // A later Acquire works: new epoch; the old port says so.
    let a = c.acquire(&acquire_req("sim:pattern", 8000, 100, 100, 2)).unwrap();
    assert_eq!(a.epoch, 2);
    assert!(matches!(port.wait(1_000_000, PATIENCE), Err(Error::Restarted)));
    let port2 = b.port();
    wait_frame(&port2, 200);
    assert_eq!(read_frames(&port2, 200, 200)[0][0], pattern_sample(200, 0));
}

#[test]
fn an_unplugged_device_ends_in_device_lost() {
    let dir = TempDir::new("unplug");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:unplug", 8000, 100, 100, 2)).unwrap();
    let port = b.port();
    match port.wait(1_000_000, PATIENCE) {
        Err(Error::Device { code, message }) => {
            assert_eq!(code, error_code::DEVICE_LOST);
            assert!(message.contains("unplugged"), "{message}");
        }
        other => panic!("expected a device error, got {other:?}"),
    }
    assert_eq!(port.info().unwrap().last_frame_index, 4000);
}

#[test]
fn the_rate_estimate_is_published() {
    let dir = TempDir::new("rate");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:silence", 48000, 480, 100, 2)).unwrap();
    let port = b.port();
    wait_frame(&port, 9600);
    // Only that it is there and plausible; its accuracy is measured, not tested (docs/broker.md).
    let r = port.info().unwrap().rate_estimate_hz;
    assert!(r > 24_000.0 && r < 96_000.0, "rate estimate {r}");
}

/// A simulated device whose thread is stopped (SIGSTOP of bassd) catches up
/// in a burst when it runs again; the burst's chunks are flagged LATE, their frames and
/// timestamps are still exact, and nothing is counted as a gap.
#[test]
fn a_device_that_falls_behind_flags_its_catch_up_chunks_late() {
    let dir = TempDir::new("late");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 48000, 480, 400, 2)).unwrap();
    let port = b.port();
    let before = wait_frame(&port, 4800);
    b.signal(libc::SIGSTOP);
    // The condition under test, not a timing assertion: 300 ms without the CPU puts the
    // device 30 chunks (10 ms each) behind.
    std::thread::sleep(std::time::Duration::from_millis(300));
    b.signal(libc::SIGCONT);
    let first = before + 1;
    let last = wait_frame(&port, before + 48000);
    let data = read_frames(&port, first, last);
    for (c, chan) in data.iter().enumerate() {
        for (i, &s) in chan.iter().enumerate() {
            assert_eq!(
                s,
                pattern_sample(first + i as u64, c as u32),
                "frame {} channel {c}",
                first + i as u64
            );
        }
    }
    let t0 = port.chunk_info(1).unwrap().mono_ns;
    let mut late = 0;
    for k in (first - 1) / 480..last / 480 {
        let ci = port.chunk_info(480 * k + 1).unwrap();
        assert_eq!(ci.mono_ns - t0, k * 10_000_000, "chunk {k} keeps its due time");
        assert_eq!(ci.flags & (chunk_flags::GAP | chunk_flags::DISCONTINUITY), 0, "chunk {k}");
        late += usize::from(ci.flags & chunk_flags::LATE != 0);
    }
    assert!(late >= 1, "no chunk of the catch-up after a 300 ms stop is flagged LATE");
    let info = port.info().unwrap();
    assert_eq!((info.xruns, info.gap_frames), (0, 0));
}

/// `sim:latestamps` feeds the estimator, through the capture
/// path, stamps as a starved thread sees them (catch-up bursts every 100 ms, a 500 ms stall
/// at 2 s, 6 s, ...), made up from the device clock so they are the same on any machine.
/// The published estimate stays within ±20 ppm of the exact 48 kHz from 4 s of device time
/// on, including across the stalls (before: +1460 ppm under real load, +500 ppm after a stall).
#[test]
fn injected_late_stamps_keep_the_published_rate_estimate_within_20_ppm() {
    let dir = TempDir::new("latestamps");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:latestamps", 48000, 32, 6000, 2)).unwrap();
    let port = b.port();
    let mut worst: f64 = 0.0;
    // Device seconds 4..8.5: across the stall at 6..6.5 s and 2 s after it.
    for tenth in 40..=85u64 {
        wait_frame(&port, tenth * 4800);
        let hz = port.info().unwrap().rate_estimate_hz;
        worst = worst.max((hz / 48000.0 - 1.0).abs() * 1e6);
    }
    assert!(worst <= 20.0, "the published estimate went {worst:.1} ppm off 48 kHz");
    let d = read_frames(&port, 400_000, 400_031);
    assert_eq!(d[0][0], pattern_sample(400_000, 0));
}
