//! The reader processes of part 3: one blocked in `Port::wait`, and the seed's polling BASC
//! client.

use std::time::{Duration, Instant};

use bassport::sys::monotonic_ns;
use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, State, Writer};

use crate::procs::{finish_all, spawn_ready};

/// Child: a reader blocked in `Port::wait`; prints `lfi wake_ns data_ns` per chunk.
pub fn child_wake_reader(args: &[String]) {
    let port = match (args.get(1).map(String::as_str), args.get(2)) {
        (Some("fd"), Some(fd)) => {
            let fd: i32 = fd.parse().expect("fd number");
            // SAFETY: the parent left this descriptor open across exec for this process
            // alone (`WakePort::start_memfd`); nothing else here owns or closes it.
            let fd = unsafe { <std::os::fd::OwnedFd as std::os::fd::FromRawFd>::from_raw_fd(fd) };
            Port::from_fd(fd, &args[0]).expect("port from fd")
        }
        _ => Port::open(&args[0]).expect("open port"),
    };
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let cap = port.geometry().frames_per_chunk as usize * 8;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut out = String::new();
    crate::procs::say_ready();
    let cpu0 = crate::procs::process_cpu_ns();
    loop {
        match port.wait(nfr, Duration::from_secs(30)) {
            Ok(lfi) => {
                let woke = monotonic_ns();
                let mut bufs = [&mut l[..], &mut r[..]];
                port.get_audio_data(cap, &mut nfr, &mut bufs).expect("read");
                let read = monotonic_ns();
                let published = port.chunk_info(lfi).map(|c| c.mono_ns).unwrap_or(0);
                if published > 0 {
                    out.push_str(&format!(
                        "{lfi} {} {}\n",
                        woke.saturating_sub(published),
                        read.saturating_sub(published)
                    ));
                }
            }
            Err(Error::Stopped { .. }) => break,
            Err(e) => panic!("wake reader: {e}"),
        }
    }
    out.push_str(&format!(
        "cpu_ns={} chunks={}\n",
        crate::procs::process_cpu_ns() - cpu0,
        out.lines().count()
    ));
    print!("{out}");
}

/// Child: a callback stream (`bassport::stream::Stream`, one chunk per block, starting at
/// the live edge); on entry to the block callback it takes CLOCK_MONOTONIC and records
/// `lfi wake_ns data_ns` as `child_wake_reader` prints them (the block's `mono_ns` is its
/// chunk's publish stamp; the samples are already in hand, so both latencies are the same).
/// The callback does not allocate: it writes into a preallocated table printed at the end.
pub fn child_stream_reader(args: &[String]) {
    use bassport::stream::{Config, Control, Event, Stream};
    let cfg = Config { frames_per_call: super::WAKE_NFPC as usize, ..Config::default() };
    let mut stream = Stream::open(&args[0], cfg).expect("open stream");
    // Room for far more blocks than a run publishes; beyond it, samples are dropped, not grown.
    let mut rec: Vec<(u64, u64)> = Vec::with_capacity(1 << 16);
    crate::procs::say_ready();
    let cpu0 = crate::procs::process_cpu_ns();
    stream
        .run(
            |b| {
                let entered = monotonic_ns();
                if b.mono_ns > 0 && rec.len() < rec.capacity() {
                    rec.push((b.first_frame + b.frames as u64 - 1, entered.saturating_sub(b.mono_ns)));
                }
                Control::Continue
            },
            |e| match e {
                Event::RealtimeRefused { .. } => Control::Continue,
                _ => Control::Stop,
            },
        )
        .expect("stream");
    let cpu = crate::procs::process_cpu_ns() - cpu0;
    let mut out = String::with_capacity(rec.len() * 32 + 64);
    for (lfi, lat) in &rec {
        out.push_str(&format!("{lfi} {lat} {lat}\n"));
    }
    out.push_str(&format!("cpu_ns={cpu} chunks={}\n", rec.len()));
    print!("{out}");
}

pub(super) fn polling(readers: usize, duration: Duration) -> Vec<f64> {
    let name = "bench-poll";
    let geometry = Geometry { channels: 2, sample_rate: 44100, frames_per_chunk: 2205, chunks_on_port: 20 };
    let params = PortParams { geometry, device: "bench:poll".into(), group: None };
    let mut w = Writer::create(name, &params).expect("create port");
    let data = vec![7i32; 2205 * 2];
    let kids = spawn_ready(readers, "poll-reader", &[name.to_owned()]);
    let start = Instant::now();
    let mut next = start;
    while start.elapsed() < duration {
        next += Duration::from_millis(50);
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        let meta = ChunkMeta { mono_ns: monotonic_ns(), ..ChunkMeta::default() };
        w.publish(Source::Interleaved(&data), meta).expect("publish");
    }
    w.stop();
    let lines = finish_all(kids);
    let _ = w.remove();
    lines.iter().filter_map(|l| l.strip_prefix("lat ")).filter_map(|v| v.parse().ok()).collect()
}

/// Child: the seed's BASC `GetBlocks` loop, a periodic 250 ms task calling getAudioData.
/// Prints `lat NS` for every chunk obtained (from the chunk's publication to the poll).
pub fn child_poll_reader(args: &[String]) {
    let port = Port::open(&args[0]).expect("open port");
    let nfpc = u64::from(port.geometry().frames_per_chunk);
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let cap = 44100;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut out = String::new();
    crate::procs::say_ready();
    // Random phase, as a client started at any moment.
    std::thread::sleep(Duration::from_micros(monotonic_ns() % 250_000));
    let mut next = Instant::now();
    loop {
        next += Duration::from_millis(250);
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        let first = nfr;
        let mut bufs = [&mut l[..], &mut r[..]];
        let got = port.get_audio_data(cap, &mut nfr, &mut bufs).expect("read");
        let t = monotonic_ns();
        // The first chunk that starts at or after `first` (chunks start at k * nFPC + 1).
        let mut f = (first - 1).div_ceil(nfpc) * nfpc + 1;
        while got.frames > 0 && f + nfpc - 1 < nfr {
            if let Ok(ci) = port.chunk_info(f) {
                out.push_str(&format!("lat {}\n", t.saturating_sub(ci.mono_ns)));
            }
            f += nfpc;
        }
        if port
            .info()
            .map(|i| !matches!(i.state, Some(State::Capturing | State::Idle | State::Starting)))
            .unwrap_or(true)
        {
            break;
        }
    }
    print!("{out}");
}
