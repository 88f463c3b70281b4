//! Test reader for the network tests: reads a port (a replica) with the library's reader and
//! checks every sample of every frame index against the pattern signal
//! (`basskit::testsignal`), a GAP frame against zeros, and the accounting
//! delivered + lost + gap = requested. Follows new epochs (RESTARTED) and waits out device
//! errors (a replica whose source is unreachable). Prints one JSON line; exits 1 on any
//! wrong sample or accounting error, 2 when the frames did not come within the timeout.
//!
//! With `--from N`, the first port is read from frame N (e.g. 1: what a program reading an
//! acquisition from its start gets); `reported_loss` is the loss the library reported (the
//! `lost` count also holds zero frames that could not be told GAP), `first_delivered` the
//! first frame delivered.
//!
//! usage: pattern_reader NAME FRAMES TIMEOUT_S [--from-first | --from N]

use std::time::{Duration, Instant};

use basskit::testsignal::pattern_expected;
use bassport::format::chunk_flags;
use bassport::{Error, Port, PortInfo};

#[derive(Default, Debug)]
struct Count {
    reported_loss: u64,
    first_delivered: u64,
    delivered: u64,
    lost: u64,
    gap: u64,
    bad: u64,
    restarts: u64,
    errors: u64,
    requested: u64,
    /// The message of each device error waited out.
    error_messages: Vec<String>,
}

impl Count {
    /// Frames accounted for so far.
    fn done(&self) -> u64 {
        self.delivered + self.lost + self.gap
    }
}

/// The command line.
struct Args {
    name: String,
    /// Frames to account for.
    want: u64,
    deadline: Instant,
    /// `--from-first`: every port from its oldest frame.
    from_first: bool,
    /// `--from N`: the first port from frame N.
    from: Option<u64>,
}

impl Args {
    fn parse() -> Args {
        let a: Vec<String> = std::env::args().collect();
        if a.len() < 4 {
            eprintln!("usage: pattern_reader NAME FRAMES TIMEOUT_S [--from-first | --from N]");
            std::process::exit(64);
        }
        let (name, want) = (a[1].clone(), a[2].parse().expect("FRAMES"));
        let deadline = Instant::now() + Duration::from_secs_f64(a[3].parse().expect("TIMEOUT_S"));
        let from_first = a.iter().any(|x| x == "--from-first");
        let from = a
            .iter()
            .position(|x| x == "--from")
            .map(|i| a.get(i + 1).and_then(|n| n.parse().ok()).expect("--from N"));
        Args { name, want, deadline, from_first, from }
    }
}

fn open(name: &str, deadline: Instant) -> Option<Port> {
    while Instant::now() < deadline {
        if let Ok(p) = Port::open(name) {
            if p.info().map(|i| i.last_frame_index > 0).unwrap_or(false) {
                return Some(p);
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    None
}

fn main() {
    let a = Args::parse();
    let mut from = a.from;
    let mut c = Count::default();
    let mut first_frame = 0;
    let mut epoch = 0;
    while c.done() < a.want {
        let Some(port) = open(&a.name, a.deadline) else { break };
        let info = port.info().expect("info");
        let nfpc = u64::from(info.geometry.frames_per_chunk);
        if epoch != 0 && info.epoch != epoch {
            c.restarts += 1;
        }
        epoch = info.epoch;
        // Start at the oldest frame (first chunk of the replica) or at the live edge.
        let mut nfr = if a.from_first {
            info.last_frame_index.saturating_sub(info.frames_on_port) + 1
        } else {
            info.last_frame_index + 1
        };
        nfr = (nfr - 1) / nfpc * nfpc + 1;
        // `--from N`: the first port only, from frame N as given (no alignment).
        if let Some(n) = from.take() {
            nfr = n;
        }
        if first_frame == 0 {
            first_frame = nfr;
        }
        if !read_port(&port, &info, &a, nfr, &mut c) {
            break;
        }
    }
    c.requested = a.want;
    let total = c.delivered + c.lost + c.gap + c.bad;
    println!(
        "{{\"delivered\":{},\"lost\":{},\"gap\":{},\"bad\":{},\"requested\":{},\"restarts\":{},\"errors\":{},\"first\":{},\"epoch\":{},\"reported_loss\":{},\"first_delivered\":{},\"error_messages\":{:?}}}",
        c.delivered, c.lost, c.gap, c.bad, c.requested, c.restarts, c.errors, first_frame, epoch, c.reported_loss, c.first_delivered, c.error_messages
    );
    if c.bad > 0 {
        std::process::exit(1);
    }
    if total != a.want {
        std::process::exit(2);
    }
}

/// What [`wait`] found.
enum Waited {
    /// The frame is there.
    Ready,
    /// Not yet (or a device error waited out): wait again.
    Again,
    /// This port ended (a new epoch, its writer gone or stopped): open the port again.
    NewPort,
}

/// Reads `port` (`info`: as it was opened) from frame `nfr` until `a.want` frames are accounted for
/// (`true`), it ends (`true`: open the port again) or the deadline passes (`false`).
fn read_port(port: &Port, info: &PortInfo, a: &Args, mut nfr: u64, c: &mut Count) -> bool {
    let epoch = info.epoch;
    let ch = info.geometry.channels as usize;
    let nfpc = u64::from(info.geometry.frames_per_chunk);
    let mut bufs = vec![vec![0i32; nfpc as usize * 4]; ch];
    let mut in_error = false;
    while c.done() < a.want {
        if Instant::now() > a.deadline {
            return false;
        }
        match wait(port, nfr, &a.name, epoch, c, &mut in_error) {
            Waited::Ready => {}
            Waited::Again => continue,
            Waited::NewPort => return true,
        }
        let left = (a.want - c.done()) as usize;
        let n_max = left.min(bufs[0].len());
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        let before = nfr;
        let r = port.get_audio_data(n_max, &mut nfr, &mut outs).expect("read");
        let lost = r.loss.min(left as u64);
        c.lost += lost;
        c.reported_loss += lost;
        if c.first_delivered == 0 && r.frames > 0 {
            c.first_delivered = nfr - r.frames as u64;
        }
        let first = nfr - r.frames as u64;
        assert_eq!(first, before + r.loss, "nfr accounting");
        let take = (r.frames as u64).min(a.want - c.done());
        classify(port, &bufs, first, take, c);
    }
    true
}

/// Waits for frame `nfr` on `port`; a device error (a replica whose source is unreachable)
/// is counted once per error and waited out, unless the port has a new epoch meanwhile.
fn wait(port: &Port, nfr: u64, name: &str, epoch: u64, c: &mut Count, in_error: &mut bool) -> Waited {
    match port.wait(nfr, Duration::from_millis(200)) {
        Ok(_) => {
            *in_error = false;
            Waited::Ready
        }
        Err(Error::Timeout { .. }) | Err(Error::Interrupted) => Waited::Again,
        Err(Error::Restarted) | Err(Error::WriterGone { .. }) | Err(Error::Stopped { .. }) => Waited::NewPort,
        Err(Error::Device { message, .. }) => {
            if !*in_error {
                c.errors += 1;
                c.error_messages.push(message);
                *in_error = true;
            }
            std::thread::sleep(Duration::from_millis(20));
            // Data may still come on this port (recovery) or on a new one.
            if let Ok(p) = Port::open(name) {
                if p.info().map(|i| i.epoch != epoch).unwrap_or(false) {
                    return Waited::NewPort;
                }
            }
            Waited::Again
        }
        Err(e) => {
            eprintln!("pattern_reader: {e}");
            std::process::exit(3);
        }
    }
}

/// Counts the `take` frames read into `bufs` from frame `first`: delivered (the pattern), GAP
/// (zeros in a GAP chunk), lost or bad.
fn classify(port: &Port, bufs: &[Vec<i32>], first: u64, take: u64, c: &mut Count) {
    let ch = bufs.len();
    for i in 0..take {
        let f = first + i;
        let zero = (0..ch).all(|k| bufs[k][i as usize] == 0);
        // The chunk's entry is read after the copy: a writer far ahead (a replica
        // writing a burst after an outage) may have reused its slot meanwhile. Then
        // the frame cannot be told GAP or not: right pattern samples still count as
        // delivered, any other non-zero sample as bad, and zeros as lost (the reader
        // was lapped while classifying).
        let flags = match port.chunk_info(f) {
            Ok(ci) if ci.first_frame <= f && f < ci.first_frame + u64::from(ci.frames) => ci.flags,
            _ => {
                if (0..ch).all(|k| bufs[k][i as usize] == pattern_expected(f, k as u32)) {
                    c.delivered += 1;
                } else if zero {
                    c.lost += 1;
                } else {
                    c.bad += 1;
                }
                continue;
            }
        };
        if flags & chunk_flags::GAP != 0 {
            if zero {
                c.gap += 1
            } else {
                c.bad += 1
            }
            continue;
        }
        let ok = (0..ch).all(|k| bufs[k][i as usize] == pattern_expected(f, k as u32));
        if ok {
            c.delivered += 1;
        } else {
            if c.bad < 5 {
                eprintln!("frame {f}: got {:?}", (0..ch).map(|k| bufs[k][i as usize]).collect::<Vec<_>>());
            }
            c.bad += 1;
        }
    }
}
