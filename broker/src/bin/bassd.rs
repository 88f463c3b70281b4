//! `bassd`: the bass capture broker daemon. See docs/broker.md.

use anyhow::{Context, Result};
use bassclient::control::AcquireRequest;
use bassd::cli::Args;
use bassd::server::{self, Config};

const HELP: &str = "\
bassd: the bass audio capture broker

usage: bassd [--name NAME] [--group GROUP] [--max-port-bytes N] [--rt-priority P] [--stall-ms MS]
             [--acquire DEVICE [--rate HZ] [--frames N] [--chunks N] [--channels N] [--format F]]

  --name NAME          broker name: port bass-NAME.port, socket bass-NAME.sock in
                       $BASS_RUNTIME_DIR (default /dev/shm); default \"default\"
  --group GROUP        also let members of GROUP control the broker and read its port
  --max-port-bytes N   memory cap of one port (default 536870912 = 512 MiB)
  --rt-priority P      SCHED_FIFO priority of the capture thread; 0 = none (default 70)
  --stall-ms MS        no data for MS ms = device stalled (default 0 = max(4 chunks, 250 ms))
  --acquire DEVICE     start capturing at start-up (defaults: --rate 44100 --frames 2205
                       --chunks 20 --channels 2)
Logging: BASS_LOG=debug|info|warn (default info), on stderr.
Stops on SIGTERM / SIGINT (the port shows Stopped, the socket is removed).";

fn main() {
    bassd::init_logging();
    if let Err(e) = run() {
        eprintln!("bassd: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let valued = [
        "name",
        "group",
        "max-port-bytes",
        "rt-priority",
        "stall-ms",
        "acquire",
        "rate",
        "frames",
        "chunks",
        "channels",
        "format",
    ];
    let args = Args::parse(std::env::args().skip(1), &valued, &["help"])?;
    if args.flag("help") {
        println!("{HELP}");
        return Ok(());
    }
    if let Some(w) = args.words.first() {
        anyhow::bail!("unexpected argument {w:?} (try --help)");
    }
    let d = AcquireRequest::default();
    let acquire = match args.text("acquire") {
        None => None,
        Some(dev) => Some(AcquireRequest {
            device: dev.to_owned(),
            sample_rate: args.get("rate", d.sample_rate)?,
            frames_per_chunk: args.get("frames", d.frames_per_chunk)?,
            chunks_on_port: args.get("chunks", d.chunks_on_port)?,
            channels: args.get("channels", d.channels)?,
            format: args.text("format").map(str::to_owned),
        }),
    };
    let group = match args.text("group") {
        None => None,
        Some(g) => Some(bassd::os::group_id(g).with_context(|| format!("--group {g}"))?),
    };
    let def = Config::default();
    let cfg = Config {
        name: args.text("name").unwrap_or(&def.name).to_owned(),
        group,
        max_port_bytes: args.get("max-port-bytes", def.max_port_bytes)?,
        rt_priority: args.get("rt-priority", def.rt_priority)?,
        stall_ms: args.get("stall-ms", def.stall_ms)?,
        acquire,
    };
    bassclient::paths::check_name(&cfg.name)?;
    server::run(cfg)
}
