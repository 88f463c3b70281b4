//! `bassd`: the bass capture broker daemon. See docs/broker.md.

use anyhow::{Context, Result};
use bassd::cli::AcquireArgs;
use bassd::server::{self, Config, DEFAULT_MAX_PORT_BYTES};
use clap::Parser;

/// bassd: the bass audio capture broker
#[derive(Parser, Debug)]
#[command(
    name = "bassd",
    version,
    args_override_self = true, // a later option wins (the test rigs override their defaults)
    after_help = "Logging: BASS_LOG=debug|info|warn (default info), on stderr.\n\
                  Stops on SIGTERM / SIGINT (the port shows Stopped, the socket is removed).\n\
                  The port and the socket live in $BASS_RUNTIME_DIR (default /dev/shm)."
)]
struct BassdArgs {
    /// Broker name: port bass-NAME.port and socket bass-NAME.sock
    #[arg(long, value_name = "NAME", default_value = bassclient::paths::DEFAULT_NAME)]
    name: String,
    /// Also let members of GROUP control the broker and read its port
    #[arg(long, value_name = "GROUP")]
    group: Option<String>,
    /// Memory cap of one port in bytes
    #[arg(long, value_name = "N", default_value_t = DEFAULT_MAX_PORT_BYTES,
          value_parser = clap::value_parser!(u64).range(1..))]
    max_port_bytes: u64,
    /// SCHED_FIFO priority of the capture thread; 0 = none
    #[arg(long, value_name = "P", default_value_t = Config::default().rt_priority,
          value_parser = clap::value_parser!(i32).range(0..=99))]
    rt_priority: i32,
    /// No data for MS ms = device stalled; 0 = max(4 chunks, 250 ms)
    #[arg(long, value_name = "MS", default_value_t = 0,
          value_parser = clap::value_parser!(u64).range(0..=3_600_000))]
    stall_ms: u64,
    /// Start capturing from DEVICE at start-up (with the acquisition options below)
    #[arg(short = 'D', long = "acquire", value_name = "DEVICE")]
    acquire: Option<String>,
    /// Parameters of --acquire.
    #[command(flatten, next_help_heading = "Options of --acquire")]
    params: AcquireArgs,
}

fn main() {
    let args = BassdArgs::parse();
    bassd::init_logging();
    let cfg = config(&args).unwrap_or_else(|e| {
        eprintln!("bassd: {e:#}");
        std::process::exit(2) // a usage error, as clap's own
    });
    if let Err(e) = server::run(cfg) {
        eprintln!("bassd: {e:#}");
        std::process::exit(1);
    }
}

/// The broker configuration from the command line: the one place that builds it.
fn config(a: &BassdArgs) -> Result<Config> {
    let acquire = match &a.acquire {
        None if a.params != AcquireArgs::default() => {
            anyhow::bail!("--rate, --frames, --chunks, --channels, --format and --loop need --acquire DEVICE")
        }
        None => None,
        Some(dev) => Some(a.params.request(dev).map_err(|m| anyhow::anyhow!("--acquire {dev}: {m}"))?),
    };
    let group = match &a.group {
        None => None,
        Some(g) => Some(bassd::os::group_id(g).with_context(|| format!("--group {g}"))?),
    };
    bassclient::paths::check_name(&a.name).with_context(|| format!("--name {}", a.name))?;
    Ok(Config {
        name: a.name.clone(),
        group,
        max_port_bytes: a.max_port_bytes,
        rt_priority: a.rt_priority,
        stall_ms: a.stall_ms,
        acquire,
    })
}
