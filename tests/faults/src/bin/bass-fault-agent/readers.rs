//! The readers: copying, waiting and zero-copy readers, the stepped reader, and the
//! follower across epochs.

use std::io::BufRead;
use std::sync::atomic::Ordering;
use std::time::Duration;

use bass_faults::count_corrupted;
use basskit::testsignal::pattern_expected;
use bassport::{Error, Port, State};
use clap::{Args, ValueEnum};

use bassport::sys::monotonic_ns;

use super::writer::own_status_kb;
use super::*;

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(super) enum ReadMode {
    /// bass_get_audio_data into the reader's buffers.
    Copy,
    /// Block in wait until the frames are published, then copy.
    Wait,
    /// Zero-copy view, read in place.
    View,
}

#[derive(Args)]
pub(super) struct ReaderArgs {
    #[command(flatten)]
    port: PortArg,
    #[arg(long, value_enum, default_value_t = ReadMode::Copy)]
    mode: ReadMode,
    /// Frames per read.
    #[arg(long, default_value_t = 64)]
    n: usize,
    /// Pause between reads, µs.
    #[arg(long = "pause-us", default_value_t = 0)]
    pause_us: u64,
    /// Print a `LOSS` line for every read that lost frames.
    #[arg(long = "log-loss")]
    log_loss: bool,
}

#[derive(Args)]
pub(super) struct SteppedArgs {
    #[command(flatten)]
    port: PortArg,
    /// Frames per read.
    #[arg(long, default_value_t = 1 << 20)]
    n: usize,
    /// The first frame to read.
    #[arg(long, default_value_t = 1)]
    nfr: u64,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(super) enum Expect {
    /// Silence: every sample 0.
    Zero,
    /// The test pattern.
    Pattern,
}

#[derive(Args)]
pub(super) struct FollowArgs {
    #[command(flatten)]
    port: PortArg,
    /// Frames per read.
    #[arg(long, default_value_t = 480)]
    n: usize,
    #[arg(long, value_enum, default_value_t = Expect::Zero)]
    expect: Expect,
}

/// Reads the pattern until the writer stops and every frame is accounted for; checks every
/// sample; prints delivered, lost, corrupted, requested (= frames covered) and whether the
/// last frame index ever went backwards.
pub(super) fn reader(a: &ReaderArgs) {
    let port = open(&a.port);
    let (mode, n) = (a.mode, a.n);
    let pause = Duration::from_micros(a.pause_us);
    let log_loss = a.log_loss;
    let channels = port.geometry().channels as usize;
    let nfop = port.frames_on_port();
    let mut bufs = vec![vec![0i32; n.min(nfop as usize)]; channels];
    say!("ready pid={}", std::process::id());
    let (mut nfr, start) = (1u64, 1u64);
    let (mut delivered, mut lost, mut corrupted, mut reads, mut loss_events) = (0u64, 0u64, 0u64, 0u64, 0u64);
    let (mut last_lfi, mut regressions, mut max_loss, mut view_overwritten) = (0u64, 0u64, 0u64, 0u64);
    loop {
        if mode == ReadMode::Wait {
            match port.wait(nfr + n as u64 - 1, Duration::from_secs(60)) {
                Ok(_) | Err(Error::Stopped { .. }) => {}
                Err(e) => panic!("wait: {e}"),
            }
        }
        let info = port.info().expect("info");
        if info.last_frame_index < last_lfi {
            regressions += 1;
        }
        last_lfi = info.last_frame_index;
        let before = nfr;
        let (frames, loss) = if mode == ReadMode::View {
            let v = port.view(n, &mut nfr).expect("view");
            // Read in place (Relaxed atomic loads), then ask which frames may be overwritten.
            for (c, buf) in bufs.iter_mut().enumerate() {
                let ring = port.channel_ring(c).expect("channel");
                let (s0, l0) = v.segments[0];
                let (s1, l1) = v.segments[1];
                ring.copy_to(s0, &mut buf[..l0]);
                ring.copy_to(s1, &mut buf[l0..l0 + l1]);
            }
            let over = port.view_overwritten(&v) as usize;
            view_overwritten += over as u64;
            for buf in bufs.iter_mut() {
                buf.copy_within(over..v.frames, 0);
            }
            (v.frames - over, v.loss + over as u64)
        } else {
            let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
            let r = port.get_audio_data(n, &mut nfr, &mut outs).expect("get_audio_data");
            (r.frames, r.loss)
        };
        reads += 1;
        let first = before + loss;
        corrupted += count_corrupted(first, frames, &bufs);
        delivered += frames as u64;
        lost += loss;
        if loss > 0 {
            loss_events += 1;
            max_loss = max_loss.max(loss);
            if log_loss {
                let after = port.info().expect("info").last_frame_index;
                say!(
                    "LOSS nfr_before={before} loss={loss} n={frames} lfi_before={} lfi_after={after} nfop={nfop}",
                    info.last_frame_index
                );
            }
        }
        if frames == 0 && loss == 0 {
            let info = port.info().expect("info");
            if info.state == Some(State::Stopped) && nfr > info.last_frame_index {
                break;
            }
        }
        if !pause.is_zero() {
            std::thread::sleep(pause);
        }
    }
    say!(
        "RESULT delivered={delivered} lost={lost} corrupted={corrupted} requested={} reads={reads} loss_events={loss_events} max_loss={max_loss} lfi_regressions={regressions} view_overwritten={view_overwritten} rss_kb={}",
        nfr - start,
        own_status_kb("VmRSS")
    );
}

/// One read per "read" line on stdin, reported as a `READ` line.
pub(super) fn stepped(a: &SteppedArgs) {
    let port = open(&a.port);
    let n = a.n;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; n.min(port.frames_on_port() as usize)]; channels];
    let mut nfr = a.nfr;
    say!("ready pid={}", std::process::id());
    let stdin = std::io::stdin();
    for line in stdin.lock().lines() {
        let line = line.expect("stdin");
        if line.trim() != "read" {
            break;
        }
        let lfi_before = port.info().expect("info").last_frame_index;
        let before = nfr;
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        let r = port.get_audio_data(n, &mut nfr, &mut outs).expect("get_audio_data");
        let lfi_after = port.info().expect("info").last_frame_index;
        let first = before + r.loss;
        let corrupted = count_corrupted(first, r.frames, &bufs);
        let stale = (0..r.frames).filter(|&i| bufs[0][i] != pattern_expected(first + i as u64, 0)).count();
        say!(
            "READ nfr_before={before} n={} loss={} nfr={nfr} first={first} corrupted={corrupted} stale={stale} lfi_before={lfi_before} lfi_after={lfi_after}",
            r.frames, r.loss
        );
    }
}

/// Follows the port by name across acquisitions until stdin closes: reads every block,
/// checks the content (`--expect zero` for silence, `pattern` for the test pattern), and
/// prints `DEVICE code=.. at_ns=..` when the acquisition ends on a device error and
/// `EPOCH e at_ns=..` for every port (epoch) it reads.
pub(super) fn follow(a: &FollowArgs) {
    let path = a.port.path();
    let n = a.n;
    let expect_zero = a.expect == Expect::Zero;
    let stop = stdin_stop_flag();
    let port0 = open(&a.port);
    say!("ready pid={} epoch={}", std::process::id(), port0.epoch());
    drop(port0);
    let (mut delivered, mut lost, mut corrupted, mut epochs, mut errors) = (0u64, 0u64, 0u64, 0u64, 0u64);
    let mut last_epoch = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let port = match Port::open_path(path) {
            Ok(p) if p.epoch() != last_epoch => p,
            Ok(_) | Err(Error::NotFound { .. } | Error::NotReady) => {
                std::thread::sleep(Duration::from_millis(5));
                continue;
            }
            Err(e) => panic!("reopen: {e}"),
        };
        last_epoch = port.epoch();
        epochs += 1;
        say!("EPOCH {} at_ns={}", last_epoch, monotonic_ns());
        let mut bufs =
            vec![vec![0i32; n.min(port.frames_on_port() as usize)]; port.geometry().channels as usize];
        let mut nfr = 1u64;
        while !stop.load(Ordering::Relaxed) {
            match port.wait(nfr + n as u64 - 1, Duration::from_millis(500)) {
                Ok(_) | Err(Error::Timeout { .. }) => {}
                Err(Error::Device { code, message }) => {
                    errors += 1;
                    say!("DEVICE code={code} at_ns={} message={}", monotonic_ns(), message.replace(' ', "_"));
                    break;
                }
                Err(Error::Restarted | Error::Stopped { .. }) => break,
                Err(e) => panic!("wait: {e}"),
            }
            let before = nfr;
            let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
            let r = port.get_audio_data(n, &mut nfr, &mut outs).expect("get_audio_data");
            if expect_zero {
                corrupted += bufs
                    .iter()
                    .map(|b| b[..r.frames].iter().filter(|&&s| s != 0).count() as u64)
                    .sum::<u64>();
            } else {
                corrupted += count_corrupted(before + r.loss, r.frames, &bufs);
            }
            delivered += r.frames as u64;
            lost += r.loss;
        }
    }
    say!("RESULT delivered={delivered} lost={lost} corrupted={corrupted} epochs={epochs} device_errors={errors}");
}
