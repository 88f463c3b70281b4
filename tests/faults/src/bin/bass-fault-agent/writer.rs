//! The pattern writer: paced on absolute deadlines or unpaced, reporting how late it ever was.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use basskit::testsignal::fill_pattern_interleaved;
use bassport::{ChunkMeta, Geometry, PortParams, Source, Writer};
use clap::Args;

use bassport::sys::monotonic_ns;

use super::*;

#[derive(Args)]
pub(super) struct WriterArgs {
    #[command(flatten)]
    port: PortArg,
    #[arg(long, default_value_t = 2)]
    channels: u32,
    #[arg(long, default_value_t = 48000)]
    rate: u32,
    /// Frames per chunk.
    #[arg(long, default_value_t = 64)]
    nfpc: u32,
    /// Chunks on the port.
    #[arg(long, default_value_t = 8)]
    ncop: u32,
    /// One chunk every U µs on absolute deadlines (0: unpaced; at most an hour).
    #[arg(long = "pace-us", default_value_t = 0,
          value_parser = clap::value_parser!(u64).range(..=3_600_000_000))]
    pace_us: u64,
    /// Stop after K chunks (0: no limit).
    #[arg(long, default_value_t = 0)]
    chunks: u64,
    /// Stop after S seconds (0: no limit).
    #[arg(long, default_value_t = 0)]
    seconds: u64,
    /// After `ready`, wait for a line on stdin before publishing.
    #[arg(long = "wait-go")]
    wait_go: bool,
    /// Group that may read the port.
    #[arg(long)]
    group: Option<u32>,
}

/// Publishes the pattern signal, paced on absolute deadlines or unpaced; reports how late
/// it ever was (a stalled or killed reader must not delay it).
pub(super) fn writer(a: &WriterArgs) {
    let geometry = Geometry {
        channels: a.channels,
        sample_rate: a.rate,
        frames_per_chunk: a.nfpc,
        chunks_on_port: a.ncop,
    };
    let mut w = Writer::create_at(
        a.port.path(),
        &PortParams { geometry: geometry.clone(), device: "fault-agent".into(), group: a.group },
    )
    .expect("create port");
    say!("ready pid={} epoch={}", std::process::id(), w.epoch());
    let stop = if a.wait_go {
        let mut go = String::new();
        std::io::stdin().read_line(&mut go).expect("stdin");
        stdin_stop_flag()
    } else {
        stdin_stop_flag()
    };
    let (chunks, seconds) = (a.chunks, a.seconds);
    let pace_ns = a.pace_us * 1000; // at most 3.6e12: no overflow
    let started = Instant::now();
    let mut chunk = vec![0i32; (geometry.frames_per_chunk * geometry.channels) as usize];
    let mut deadline = monotonic_ns();
    let (mut max_late_ns, mut max_publish_ns, mut published) = (0u64, 0u64, 0u64);
    let mut rss_start = 0;
    loop {
        if stop.load(Ordering::Relaxed)
            || (chunks > 0 && published >= chunks)
            || (seconds > 0 && started.elapsed() >= Duration::from_secs(seconds))
        {
            break;
        }
        if pace_ns > 0 {
            deadline += pace_ns;
            sleep_until(deadline);
            max_late_ns = max_late_ns.max(monotonic_ns().saturating_sub(deadline));
        }
        fill_pattern_interleaved(&mut chunk, geometry.channels, w.last_frame_index() + 1);
        let t0 = Instant::now();
        w.publish(Source::Interleaved(&chunk), ChunkMeta::default()).expect("publish");
        max_publish_ns = max_publish_ns.max(t0.elapsed().as_nanos() as u64);
        published += 1;
        if published == 1000 {
            rss_start = own_status_kb("VmRSS");
        }
    }
    let last = w.last_frame_index();
    w.stop();
    say!(
        "RESULT last={last} chunks={published} max_late_us={} max_publish_us={} rss_start_kb={rss_start} rss_end_kb={} anon_end_kb={} secs={:.3}",
        max_late_ns / 1000,
        max_publish_ns / 1000,
        own_status_kb("VmRSS"),
        own_status_kb("RssAnon"),
        started.elapsed().as_secs_f64()
    );
}

pub(super) fn own_status_kb(field: &str) -> u64 {
    let text = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    text.lines()
        .find_map(|l| l.strip_prefix(field).and_then(|r| r.strip_prefix(':')))
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

/// Sleeps until CLOCK_MONOTONIC `deadline_ns` (absolute, so pacing does not drift).
fn sleep_until(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: a valid timespec; an absolute sleep on CLOCK_MONOTONIC with no remainder pointer.
    unsafe { libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut()) };
}
