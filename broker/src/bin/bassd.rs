//! `bassd`: the bass capture broker daemon. See docs/broker.md.
#![forbid(unsafe_code)]

use anyhow::{Context, Result};
use bassd::request::Limits;
use bassd::server::{self, Config};
use basskit::args::AcquireArgs;
use clap::Parser;

/// bassd: the bass audio capture broker
#[derive(Parser, Debug)]
#[command(
    name = "bassd",
    version,
    args_override_self = true, // a later option wins (the test rigs override their defaults)
    after_help = "Logging: BASS_LOG=debug|info|warn (default info), on stderr.\n\
                  Stops on SIGTERM / SIGINT (the port shows Stopped, the socket is removed).\n\
                  The port and the socket live in $BASS_RUNTIME_DIR (default /run/bass for a\n\
                  broker run as root, else /dev/shm)."
)]
struct BassdArgs {
    /// Broker name: port bass-NAME.port and socket bass-NAME.sock
    #[arg(long, value_name = "NAME", default_value = bassport::paths::DEFAULT_NAME)]
    name: String,
    /// Also let members of GROUP control the broker and read its port
    #[arg(long, value_name = "GROUP")]
    group: Option<String>,
    /// SCHED_FIFO priority of the capture thread; 0 = none
    #[arg(long, value_name = "P", default_value_t = Config::default().rt_priority,
          value_parser = clap::value_parser!(i32).range(0..=99))]
    rt_priority: i32,
    /// No data for MS ms = device stalled; 0 = max(4 chunks, 250 ms)
    #[arg(long, value_name = "MS", default_value_t = 0,
          value_parser = clap::value_parser!(u64).range(0..=3_600_000))]
    stall_ms: u64,
    /// Longest wait for a device to open and configure (ms): an Acquire whose device open
    /// has not returned by then is refused (the open is left behind), and the broker answers
    /// every other request meanwhile
    #[arg(long, value_name = "MS", default_value_t = server::DEFAULT_OPEN_TIMEOUT.as_millis() as u64,
          value_parser = clap::value_parser!(u64).range(1..=600_000))]
    open_timeout_ms: u64,
    /// What holds the port: `file` (a file in the runtime directory; readers open it by path,
    /// and its last window stays readable after the broker dies) or `memfd` (a sealed memfd
    /// handed to readers over the control socket: its size cannot change under a reader, so
    /// reads skip a per-call fstat; it lives only while the broker or a reader holds it)
    #[arg(long, value_name = "BACKING", default_value = "file", value_parser = ["file", "memfd"])]
    port_backing: String,
    /// Under systemd (NOTIFY_SOCKET set): how long readers wait for a restarted bassd to take
    /// its port back from the fd store and go on (ms); 0 = do not use the fd store, a restart
    /// ends the acquisition (docs/broker.md, "Restarts that readers ride through")
    #[arg(long, value_name = "MS", default_value_t = bassd::supervise::DEFAULT_RESTART_GRACE_MS,
          value_parser = clap::value_parser!(u32).range(0..=i64::from(bassport::format::MAX_RESTART_GRACE_MS)))]
    restart_grace_ms: u32,
    /// Start capturing from DEVICE at start-up (with the acquisition options below)
    #[arg(short = 'D', long = "acquire", value_name = "DEVICE")]
    acquire: Option<String>,
    /// Parameters of --acquire.
    #[command(flatten, next_help_heading = "Options of --acquire")]
    params: AcquireArgs,
    /// Hardening: what clients may ask for (docs/broker.md, "Device policy" and "Limits").
    #[command(flatten, next_help_heading = "Hardening")]
    hardening: Hardening,
}

/// The operator's bounds on what control clients may make the broker do.
#[derive(clap::Args, Debug)]
struct Hardening {
    /// Also let clients open devices matching the glob PATTERN (* ? [..]); repeatable;
    /// e.g. 'sim:file:/data/*', 'bass_jack'
    #[arg(long = "allow-device", value_name = "PATTERN")]
    allow_device: Vec<String>,
    /// What a client's Acquire may ask for (the mirror has the same options).
    #[command(flatten)]
    limits: Limits,
    /// Close control connections idle this long (ms)
    #[arg(long, value_name = "MS", default_value_t = server::DEFAULT_IDLE_TIMEOUT.as_millis() as u64,
          value_parser = clap::value_parser!(u64).range(1..))]
    idle_timeout_ms: u64,
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
    bassport::paths::check_name(&a.name).with_context(|| format!("--name {}", a.name))?;
    let h = &a.hardening;
    Ok(Config {
        name: a.name.clone(),
        group,
        rt_priority: a.rt_priority,
        stall_ms: a.stall_ms,
        acquire,
        policy: bassd::policy::DevicePolicy::new(&h.allow_device).map_err(anyhow::Error::msg)?,
        limits: h.limits.clone(),
        idle_timeout: std::time::Duration::from_millis(h.idle_timeout_ms),
        open_timeout: std::time::Duration::from_millis(a.open_timeout_ms),
        restart_grace_ms: a.restart_grace_ms,
        port_backing: if a.port_backing == "memfd" {
            bassport::Backing::Memfd
        } else {
            bassport::Backing::File
        },
    })
}
