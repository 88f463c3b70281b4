//! `bass`: the command-line tool of the bass broker: devices, acquire, stop, status, blocks.
//! See docs/broker.md.

use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use bassclient::control::{AcquireRequest, Client};
use bassclient::format::State;
use bassclient::{Error, Port};
use bassd::cli::Args;

const HELP: &str = "\
bass: command-line tool of the bass audio broker

usage: bass [--name BROKER] COMMAND ...
  devices                         list capture devices (a table)
  acquire [DEVICE] [--rate HZ] [--frames N] [--chunks N] [--channels N] [--format F] [--wait]
                                  start an acquisition (defaults: hw:1,0 44100 2205 20 2);
                                  --wait also waits for the first chunk and prints the delay
  stop                            stop the acquisition
  status                          state of the broker and its port
  blocks [--block N] [--count N] [--seconds S] [--offset N]
                                  read blocks of N frames (default nFramesPerChunk) from the
                                  port like the BASC client and print one line per block:
                                  first frame, frames, loss, RMS and peak level per channel
--name BROKER selects the broker (default \"default\"); $BASS_RUNTIME_DIR its directory.";

fn main() {
    if let Err(e) = run() {
        eprintln!("bass: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let valued =
        ["name", "rate", "frames", "chunks", "channels", "format", "block", "count", "seconds", "offset"];
    let args = Args::parse(std::env::args().skip(1), &valued, &["help", "wait"])?;
    let name = args.text("name").unwrap_or(bassclient::paths::DEFAULT_NAME).to_owned();
    let Some(cmd) = args.words.first().map(String::as_str) else {
        println!("{HELP}");
        return Ok(());
    };
    if args.flag("help") {
        println!("{HELP}");
        return Ok(());
    }
    let connect = || Client::connect(&name).with_context(|| format!("is bassd --name {name} running?"));
    match cmd {
        "devices" => {
            let devs = connect()?.list_devices()?;
            let w = devs.iter().map(|d| d.name.len()).max().unwrap_or(6).max(6);
            println!("{:<w$}  DESCRIPTION", "DEVICE");
            for d in devs {
                println!("{:<w$}  {}", d.name, d.description);
            }
        }
        "acquire" => {
            let d = AcquireRequest::default();
            let req = AcquireRequest {
                device: args.words.get(1).cloned().unwrap_or(d.device),
                sample_rate: args.get("rate", d.sample_rate)?,
                frames_per_chunk: args.get("frames", d.frames_per_chunk)?,
                chunks_on_port: args.get("chunks", d.chunks_on_port)?,
                channels: args.get("channels", d.channels)?,
                format: args.text("format").map(str::to_owned),
            };
            let t0 = Instant::now();
            let a = connect()?.acquire(&req)?;
            let replied = t0.elapsed();
            println!(
                "acquiring {} (format {}), epoch {}, port {}",
                req.device,
                a.format,
                a.epoch,
                a.port.display()
            );
            if args.flag("wait") {
                let port = Port::open_path(&a.port)?;
                port.wait(u64::from(req.frames_per_chunk), Duration::from_secs(10))?;
                let first = t0.elapsed();
                println!(
                    "reply after {:.3} ms; first chunk published {:.3} ms after the request",
                    replied.as_secs_f64() * 1e3,
                    first.as_secs_f64() * 1e3
                );
            }
        }
        "stop" => {
            connect()?.stop()?;
            println!("stopped");
        }
        "status" => {
            let s = connect()?.status()?;
            let state = s.state().map_or("unknown".to_string(), |st| format!("{st:?}").to_lowercase());
            println!("broker      {name} (pid {}, version {})", s.broker_pid, s.broker_version);
            println!(
                "state       {state}{}",
                if s.error_code != 0 { format!(" (error code {})", s.error_code) } else { String::new() }
            );
            if !s.message.is_empty() {
                println!("message     {}", s.message);
            }
            if s.epoch > 0 {
                println!("device      {} ({})", s.device, s.format);
                println!(
                    "geometry    {} Hz, {} ch, {} frames x {} chunks",
                    s.sample_rate, s.channels, s.frames_per_chunk, s.chunks_on_port
                );
                println!("epoch       {}", s.epoch);
                println!("last frame  {}", s.last_frame_index);
                println!("chunks      {}", s.chunks_published);
                println!("xruns       {} ({} zero-filled frames)", s.xruns, s.gap_frames);
                if let Ok(i) = Port::open_path(std::path::Path::new(&s.port)).and_then(|p| p.info()) {
                    println!("lost upstr. {} frames (network or source side of a replica; in the zero-filled frames)", i.lost_upstream_frames)
                }
                println!("rate est.   {:.3} Hz", s.rate_estimate_hz);
                println!("port        {}", s.port);
            }
        }
        "blocks" => blocks(&name, &args)?,
        other => bail!("unknown command {other:?} (try --help)"),
    }
    Ok(())
}

fn open_when_ready(name: &str, deadline: Instant) -> Result<Port> {
    loop {
        match Port::open(name) {
            Ok(p) => return Ok(p),
            Err(e @ (Error::NotFound { .. } | Error::NotReady)) => {
                if Instant::now() > deadline {
                    return Err(e.into());
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => return Err(e.into()),
        }
    }
}

fn dbfs(x: f64) -> String {
    if x <= 0.0 {
        "  -inf".into()
    } else {
        format!("{:6.1}", 20.0 * x.log10())
    }
}

/// The BASC loop: blocks of N frames, following each other without loss unless the port
/// overtakes us; one line per block.
fn blocks(name: &str, args: &Args) -> Result<()> {
    let count: u64 = args.get("count", 0)?;
    let seconds: f64 = args.get("seconds", 0.0)?;
    let offset: i64 = args.get("offset", 0)?;
    let end = (seconds > 0.0).then(|| Instant::now() + Duration::from_secs_f64(seconds));
    let mut port = open_when_ready(name, Instant::now() + Duration::from_secs(10))?;
    let mut n_blocks = 0u64;
    'reopen: loop {
        let g = port.geometry().clone();
        let block: usize = args.get("block", g.frames_per_chunk as usize)?;
        if block == 0 {
            bail!("--block 0");
        }
        let ch = g.channels as usize;
        println!(
            "port {name}: epoch {}, {} Hz, {} ch, {} frames/chunk, {} chunks; blocks of {block} frames",
            port.epoch(),
            g.sample_rate,
            ch,
            g.frames_per_chunk,
            g.chunks_on_port
        );
        let lfi = port.info()?.last_frame_index;
        let mut nfr = (lfi as i64 + 1 + offset).max(1) as u64;
        let mut bufs = vec![vec![0i32; block]; ch];
        loop {
            if count > 0 && n_blocks >= count || end.is_some_and(|e| Instant::now() >= e) {
                return Ok(());
            }
            // Collect one block (getAudioData may return fewer frames than asked).
            let (mut got, mut loss) = (0usize, 0u64);
            while got < block {
                if end.is_some_and(|e| Instant::now() >= e) {
                    return Ok(());
                }
                let want = nfr + (block - got) as u64 - 1;
                match port.wait(want.min(nfr + g.frames_per_chunk as u64), Duration::from_millis(200)) {
                    Ok(_) | Err(Error::Timeout { .. }) => {}
                    Err(Error::Restarted) => {
                        println!("-- a new acquisition replaced the port; reopening");
                        port = open_when_ready(name, Instant::now() + Duration::from_secs(10))?;
                        continue 'reopen;
                    }
                    Err(e @ (Error::Stopped { .. } | Error::Device { .. } | Error::WriterGone { .. })) => {
                        println!("-- acquisition ended: {e}");
                        return Ok(());
                    }
                    Err(e) => return Err(e.into()),
                }
                let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| &mut b[got..]).collect();
                let r = port.get_audio_data(block - got, &mut nfr, &mut outs)?;
                if r.loss > 0 {
                    // The port overtook us: the block restarts at the oldest frame on the port.
                    loss += r.loss;
                    if got > 0 {
                        for b in bufs.iter_mut() {
                            b.copy_within(got..got + r.frames, 0);
                        }
                        got = 0;
                    }
                }
                got += r.frames;
            }
            n_blocks += 1;
            let start = nfr - block as u64;
            let mut line =
                format!("block {n_blocks:5}  frames {start:>10}..{:<10} ({block}) loss {loss:<6}", nfr - 1);
            for (c, b) in bufs.iter().enumerate() {
                let (mut sum, mut peak) = (0f64, 0f64);
                for &s in b.iter() {
                    let x = f64::from(s) / 2_147_483_648.0;
                    sum += x * x;
                    peak = peak.max(x.abs());
                }
                let rms = (sum / block as f64).sqrt();
                line.push_str(&format!(" | ch{c} rms {} peak {} dBFS", dbfs(rms), dbfs(peak)));
            }
            println!("{line}");
            if port.info().map(|i| i.state == Some(State::Superseded)).unwrap_or(false) {
                continue 'reopen;
            }
        }
    }
}
