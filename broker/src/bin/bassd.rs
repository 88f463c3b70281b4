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
                       $BASS_RUNTIME_DIR (default /run/bass as root, else /dev/shm);
                       default \"default\"
  --group GROUP        also let members of GROUP control the broker and read its port
  --max-port-bytes N   memory cap of one port (default 536870912 = 512 MiB)
  --rt-priority P      SCHED_FIFO priority of the capture thread; 0 = none (default 70)
  --stall-ms MS        no data for MS ms = device stalled (default 0 = max(4 chunks, 250 ms))
  --acquire DEVICE     start capturing at start-up (defaults: --rate 44100 --frames 2205
                       --chunks 20 --channels 2)
Hardening (docs/broker.md, Device policy and Limits):
  --allow-device PAT   also let clients open devices matching the glob PAT (* ? [..]);
                       repeatable; e.g. 'sim:file:/data/*', 'bass_jack'
  --min-chunk-us US    shortest chunk a client may ask for (default 500)
  --max-rate HZ        highest sample rate (default 192000; at most 768000)
  --max-channels N     most channels (default 32; at most 64)
  --max-window-s S     longest window (default 3600)
  --idle-timeout-ms MS close control connections idle this long (default 30000)
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
    // --- h-server hardening options (issue 9/14) ---
    let (allow_devices, argv) = take_repeated(std::env::args().skip(1), "allow-device")?;
    let hardening = ["min-chunk-us", "max-rate", "max-channels", "max-window-s", "idle-timeout-ms"];
    let valued: Vec<&str> = valued.iter().chain(hardening.iter()).copied().collect();
    let args = Args::parse(argv, &valued, &["help"])?;
    let dl = bassd::request::Limits::default();
    let limits = bassd::request::Limits {
        min_chunk_us: args.get("min-chunk-us", dl.min_chunk_us)?,
        max_rate: args.get("max-rate", dl.max_rate)?,
        max_channels: args.get("max-channels", dl.max_channels)?,
        max_window_s: args.get("max-window-s", dl.max_window_s)?,
    };
    let idle_ms: u64 = args.get("idle-timeout-ms", server::DEFAULT_IDLE_TIMEOUT.as_millis() as u64)?;
    if idle_ms == 0 {
        anyhow::bail!("--idle-timeout-ms 0: must be at least 1");
    }
    let policy = bassd::policy::DevicePolicy::new(&allow_devices).map_err(anyhow::Error::msg)?;
    // --- end of the hardening options ---
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
        policy,
        limits,
        idle_timeout: std::time::Duration::from_millis(idle_ms),
    };
    bassclient::paths::check_name(&cfg.name)?;
    server::run(cfg)
}

/// Takes every `--NAME VALUE` / `--NAME=VALUE` out of `argv` (a repeatable option).
fn take_repeated(argv: impl Iterator<Item = String>, name: &str) -> Result<(Vec<String>, Vec<String>)> {
    let (flag, prefix) = (format!("--{name}"), format!("--{name}="));
    let (mut values, mut rest) = (Vec::new(), Vec::new());
    let mut it = argv;
    while let Some(a) = it.next() {
        if a == flag {
            values.push(it.next().with_context(|| format!("option {flag} needs a value"))?);
        } else if let Some(v) = a.strip_prefix(&prefix) {
            values.push(v.to_owned());
        } else {
            rest.push(a);
        }
    }
    Ok((values, rest))
}
