//! The `bass` command line (clap derive) and its small commands: devices, acquire, stop,
//! status, completions. See docs/broker.md.

use std::io::Write;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use bassport::control::Client;
use bassport::paths::DEFAULT_NAME;
use bassport::{Error, Port};
use clap::{CommandFactory, Parser, Subcommand};
use serde_json::json;

use crate::blocks::{self, BlocksArgs};
use crate::exit::{self, Exit};
use crate::meter::{self, MeterArgs};
use crate::out::{self, note, outln};
use crate::plot::{self, PlotArgs};
use crate::record::{self, RecordArgs};
use basskit::args::{parse_seconds, AcquireArgs};

const EXIT_CODES: &str = "\
Exit codes: 0 success; 1 other failure; 2 usage error (or a request the broker refused as
invalid); 3 broker unreachable; 4 device error; 5 acquisition ended by a device error;
6 timeout. The broker's directory is $BASS_RUNTIME_DIR (default /dev/shm).";

/// bass: command-line tool of the bass audio broker
#[derive(Parser, Debug)]
#[command(name = "bass", version, after_help = EXIT_CODES, args_override_self = true)]
pub struct Cli {
    /// Broker name (port bass-NAME.port, socket bass-NAME.sock)
    #[arg(long, global = true, value_name = "BROKER", default_value = DEFAULT_NAME)]
    pub name: String,
    /// Longest wait for the broker's reply or for a port to appear, in seconds
    #[arg(long, global = true, value_name = "S", default_value = "15", value_parser = parse_seconds)]
    pub timeout: f64,
    /// What to do
    #[command(subcommand)]
    pub command: Command,
}

/// The commands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// List capture devices
    Devices {
        /// One JSON object per device and line: {"name", "description"}
        #[arg(long)]
        json: bool,
    },
    /// Start an acquisition (interrupting the running one)
    Acquire(AcquireCmd),
    /// Stop the acquisition (the port keeps its frames)
    Stop,
    /// State of the broker and of its port
    Status {
        /// One JSON object with the fields of the C struct bass_broker_status
        #[arg(long)]
        json: bool,
    },
    /// Read blocks of frames like the BASC client, one line per block
    Blocks(BlocksArgs),
    /// Live level meter: RMS and peak dBFS per channel, clip and gap markers
    Meter(MeterArgs),
    /// Draw a PNG of a WAV recording, or of the last seconds on the port (--live)
    Plot(PlotArgs),
    /// Record the port to a WAV file with a timestamp sidecar (FILE.json)
    Record(RecordArgs),
    /// Publish the port as a Lab Streaming Layer stream (liblsl loaded at run time), with a
    /// marker stream of every loss and GAP
    Lsl(crate::lsl::LslArgs),
    /// Print a shell completion script (bash, zsh, fish, elvish, powershell)
    Completions {
        /// The shell
        shell: clap_complete::Shell,
    },
}

/// `bass acquire [DEVICE...]`.
#[derive(clap::Args, Debug)]
pub struct AcquireCmd {
    /// Capture device: an ALSA PCM (hw:1,0, plughw:..., default) or sim:sine, sim:pattern, ...;
    /// several: the first is the master clock, the others follow it, resampled onto its
    /// frames, each with --channels channels (or --follower-channels), after it on the port
    /// (docs/multi-device.md)
    #[arg(value_name = "DEVICE", conflicts_with = "device_opt", value_parser = device_name, num_args = 0..)]
    pub device: Vec<String>,
    /// Capture device (as arecord -D)
    #[arg(short = 'D', long = "device", value_name = "DEVICE", id = "device_opt")]
    pub device_opt: Option<String>,
    /// Acquisition parameters.
    #[command(flatten)]
    pub params: AcquireArgs,
    /// Channels of each follower, in order, comma-separated (e.g. 4,2 for two followers; 1 to
    /// 64 each); without it every follower has --channels channels
    #[arg(long, value_name = "N,N...", value_delimiter = ',', value_parser = follower_channels)]
    pub follower_channels: Vec<u32>,
    /// Also wait for the first chunk and print how long it took
    #[arg(long)]
    pub wait: bool,
}

/// One count of `--follower-channels`: 1 to 64 (a port holds at most 64 channels).
fn follower_channels(s: &str) -> std::result::Result<u32, String> {
    match s.trim().parse::<u32>() {
        Ok(n) if (1..=64).contains(&n) => Ok(n),
        Ok(n) => Err(format!("{n} is out of range (1..=64 channels)")),
        Err(_) => Err(format!("{s:?} is not a channel count")),
    }
}

/// A device named on the command line: a bare number is the seed's positional parameters,
/// refused by name (they are options here).
fn device_name(s: &str) -> std::result::Result<String, String> {
    if !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()) {
        return Err(format!(
            "{s} is not a device name; the rate, frames per chunk and chunks are options: --rate, --frames, --chunks"
        ));
    }
    Ok(s.to_owned())
}

/// Entry point of the `bass` binary: parses, runs, prints the error and exits with its code.
pub fn main() -> ! {
    let cli = Cli::parse();
    let code = match run(&cli) {
        Ok(()) => exit::OK,
        // The reader of stdout has what it wanted (`bass blocks | head -1`): see crate::out.
        Err(e) if out::is_stdout_closed(&e) => exit::OK,
        Err(e) => {
            note!("bass: {}", describe(&e));
            exit::code_of(&e)
        }
    };
    let _ = std::io::stdout().flush();
    std::process::exit(code)
}

/// An error and its causes, each cause once: the library's errors already end with the OS
/// error they wrap (`open X: Permission denied`), which `{:#}` would print a second time.
fn describe(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let c = cause.to_string();
        if text.ends_with(&c) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&c);
    }
    text
}

pub(crate) fn connect(name: &str, timeout: Duration) -> Result<Client> {
    let mut c = Client::connect(name).map_err(|e| match e {
        // The broker runs but this user may not use it: the message says what to do.
        Error::NoBroker { .. } if e.is_access_refused() => Exit::new(exit::NO_BROKER, e.to_string()),
        Error::NoBroker { .. } => Exit::new(
            exit::NO_BROKER,
            format!("{e}; is bassd --name {name} running? Start it with `bassd --name {name}`"),
        ),
        e => {
            let code = exit::code_of(&anyhow::Error::from(Error::Protocol(String::new())));
            Exit::new(code, format!("cannot connect to the broker {name}: {e}"))
        }
    })?;
    c.set_timeout(timeout)?;
    Ok(c)
}

/// Adds the next step to a failure of a request.
fn explain(e: Error, name: &str, device: Option<&str>) -> anyhow::Error {
    let text = e.to_string();
    let hint = match &e {
        Error::Broker(m) if m.ends_with("[device]") => format!(
            "; list the devices with `bass --name {name} devices`, or try a simulated one: `bass acquire sim:sine`{}",
            device.map(|d| format!(" (device {d:?})")).unwrap_or_default()
        ),
        Error::Io { source, .. } if source.kind() == std::io::ErrorKind::TimedOut => {
            format!("; the broker {name} did not answer in time (stopped or overloaded?); raise --timeout")
        }
        _ => String::new(),
    };
    let code = exit::code_of(&anyhow::Error::from(e));
    Exit::new(code, format!("{text}{hint}")).into()
}

/// Runs one parsed command line.
pub fn run(cli: &Cli) -> Result<()> {
    let name = cli.name.as_str();
    bassport::paths::check_name(name).map_err(|e| Exit::new(exit::USAGE, format!("--name: {e}")))?;
    let timeout = Duration::from_secs_f64(cli.timeout);
    match &cli.command {
        Command::Devices { json } => {
            let devs = connect(name, timeout)?.list_devices().map_err(|e| explain(e, name, None))?;
            if *json {
                for d in devs {
                    outln!("{}", json!({"name": d.name, "description": d.description}))?;
                }
            } else {
                let w = devs.iter().map(|d| d.name.len()).max().unwrap_or(6).max(6);
                outln!("{:<w$}  DESCRIPTION", "DEVICE")?;
                for d in devs {
                    outln!("{:<w$}  {}", d.name, d.description)?;
                }
            }
        }
        Command::Acquire(a) => acquire(name, a, timeout)?,
        Command::Stop => {
            // The broker says what it did: "stopped at frame N", "already stopped at frame N", ...
            let said = connect(name, timeout)?.stop_report().map_err(|e| explain(e, name, None))?;
            outln!("{said}")?;
        }
        Command::Status { json } => status(name, *json, timeout)?,
        Command::Blocks(b) => blocks::run(name, b, timeout)?,
        Command::Record(r) => record::run(name, r, timeout)?,
        Command::Meter(m) => meter::run(name, m, timeout)?,
        Command::Lsl(l) => crate::lsl::run(name, l, timeout)?,
        Command::Plot(p) => plot::run(name, p, timeout)?,
        Command::Completions { shell } => {
            let mut script = Vec::new();
            clap_complete::generate(*shell, &mut Cli::command(), "bass", &mut script);
            out::bytes(&script)?;
        }
    }
    Ok(())
}

fn acquire(name: &str, a: &AcquireCmd, timeout: Duration) -> Result<()> {
    let default = bassport::control::AcquireRequest::default().device;
    let device = a.device.first().map(String::as_str).or(a.device_opt.as_deref()).unwrap_or(&default);
    let mut req = a.params.request(device).map_err(|m| Exit::new(exit::USAGE, m))?;
    let followers = a.device.len().saturating_sub(1);
    if !a.follower_channels.is_empty() && a.follower_channels.len() != followers {
        return Err(Exit::new(
            exit::USAGE,
            format!(
                "--follower-channels has {} count(s) for {followers} follower device(s): give one per follower, in order",
                a.follower_channels.len()
            ),
        )
        .into());
    }
    for (i, f) in a.device.iter().skip(1).enumerate() {
        let device = a.params.request(f).map_err(|m| Exit::new(exit::USAGE, m))?.device;
        // 0: as many as the master's (the protocol's default).
        let channels = a.follower_channels.get(i).copied().unwrap_or(0);
        req.followers.push(bassport::control::FollowerRequest { device, channels });
    }
    let t0 = Instant::now();
    let got = connect(name, timeout)?.acquire(&req).map_err(|e| explain(e, name, Some(device)))?;
    let replied = t0.elapsed();
    let followers: String = req.followers.iter().map(|f| format!(" + {}", f.device)).collect();
    outln!(
        "acquiring {}{followers} (format {}), epoch {}, port {}",
        req.device,
        got.format,
        got.epoch,
        got.port.display()
    )?;
    if a.wait {
        let port = open_reported(&got.port, name).context("open the new port")?;
        port.wait(u64::from(req.frames_per_chunk), timeout)?;
        let first = t0.elapsed();
        outln!(
            "reply after {:.3} ms; first chunk published {:.3} ms after the request",
            replied.as_secs_f64() * 1e3,
            first.as_secs_f64() * 1e3
        )?;
    }
    Ok(())
}

/// The port a broker reported: its path, or (a `--port-backing memfd` broker, whose port has
/// no file there) the port by name, handed over by the broker.
fn open_reported(path: &std::path::Path, name: &str) -> bassport::Result<Port> {
    match Port::open_path(path) {
        Err(bassport::Error::NotFound { .. }) => Port::open(name),
        other => other,
    }
}

fn status(name: &str, json: bool, timeout: Duration) -> Result<()> {
    let s = connect(name, timeout)?.status().map_err(|e| explain(e, name, None))?;
    let state = s.state_name();
    // Frames a replica (bass-bridge mirror) never received, from the port itself.
    let lost_upstream = (s.epoch > 0)
        .then(|| open_reported(std::path::Path::new(&s.port), name).and_then(|p| p.info()).ok())
        .flatten()
        .map_or(0, |i| i.lost_upstream_frames);
    if json {
        let v = json!({
            "broker": name, "broker_pid": s.broker_pid, "broker_version": s.broker_version,
            "state": s.state, "state_name": state, "error_code": s.error_code,
            "sample_rate": s.sample_rate, "frames_per_chunk": s.frames_per_chunk,
            "chunks_on_port": s.chunks_on_port, "channels": s.channels, "epoch": s.epoch,
            "last_frame_index": s.last_frame_index, "chunks_published": s.chunks_published,
            "xruns": s.xruns, "gap_frames": s.gap_frames, "rate_estimate_hz": s.rate_estimate_hz,
            "device": s.device, "format": s.format, "message": s.message, "port": s.port,
            "lost_upstream_frames": lost_upstream,
            "devices": s.devices,
            "replica": s.replica,
        });
        outln!("{v}")?;
        return Ok(());
    }
    outln!("broker      {name} (pid {}, version {})", s.broker_pid, s.broker_version)?;
    let code = if s.error_code != 0 { format!(" (error code {})", s.error_code) } else { String::new() };
    outln!("state       {state}{code}")?;
    if !s.message.is_empty() {
        outln!("message     {}", s.message)?;
    }
    if s.epoch > 0 {
        outln!("device      {} ({})", s.device, s.format)?;
        outln!(
            "geometry    {} Hz, {} ch, {} frames x {} chunks",
            s.sample_rate,
            s.channels,
            s.frames_per_chunk,
            s.chunks_on_port
        )?;
        outln!("epoch       {}", s.epoch)?;
        outln!("last frame  {}", s.last_frame_index)?;
        outln!("chunks      {}", s.chunks_published)?;
        outln!("xruns       {} ({} zero-filled frames)", s.xruns, s.gap_frames)?;
        if lost_upstream > 0 {
            outln!("lost upstr. {lost_upstream} frames (never received by this replica; among the zero-filled frames)")?;
        }
        outln!("rate est.   {:.3} Hz", s.rate_estimate_hz)?;
        outln!("port        {}", s.port)?;
        for d in &s.devices {
            outln!(
                "  {} {} ch {}..{}: {}, {:+.2} ppm, error {:.3} smp, {} lock(s), {} xrun(s), {} unplug(s), {} missing, {} unaligned frames",
                d.role,
                d.name,
                d.first_channel,
                d.first_channel + d.channels,
                d.state,
                d.ratio_ppm,
                d.error_estimate,
                d.locks,
                d.xruns,
                d.unplugs,
                d.missing_frames,
                d.unaligned_frames
            )?;
        }
    }
    if let Some(r) = &s.replica {
        let link = if r.link_up { "up" } else { "down" };
        outln!(
            "source      {} ({}; epoch {}, last frame {})",
            r.source,
            r.source_state,
            r.source_epoch,
            r.source_last_frame_index
        )?;
        outln!("link        {link} for {:.1} s; {} outage(s)", r.link_since_s, r.outages)?;
        outln!(
            "never recv. {} frames ({} of them not sent by the source)",
            r.gap_frames_lost,
            r.gap_frames_source
        )?;
        if r.forged_messages > 0 {
            outln!("forged      {} messages dropped (not signed by the source)", r.forged_messages)?;
        }
        match &r.source_status {
            Some(live) => outln!(
                "source live {} on {} (pid {}), last frame {}",
                live.state_name(),
                live.device,
                live.broker_pid,
                live.last_frame_index
            ),
            None => outln!(
                "source live not asked (the source allows this mirror no control: serve --allow-control), or unreachable"
            ),
        }?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(args: &[&str]) -> Result<Cli, clap::Error> {
        Cli::try_parse_from(std::iter::once("bass").chain(args.iter().copied()))
    }

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn positional_numbers_after_the_device_are_refused() {
        let e = parse(&["acquire", "sim:sine", "48000", "480", "100"]).unwrap_err();
        assert_eq!(e.exit_code(), exit::USAGE);
        assert!(e.to_string().contains("48000 is not a device name"), "{e}");
    }

    #[test]
    fn device_by_position_or_by_dash_capital_d() {
        for args in [&["acquire", "sim:sine"][..], &["acquire", "-D", "sim:sine"]] {
            let Command::Acquire(a) = parse(args).unwrap().command else { panic!("not acquire") };
            assert_eq!(a.device.first().cloned().or(a.device_opt).as_deref(), Some("sim:sine"));
        }
        assert!(parse(&["acquire", "sim:sine", "-D", "sim:pattern"]).is_err());
        let Command::Acquire(a) = parse(&["acquire", "sim:field", "sim:field?ppm=87"]).unwrap().command
        else {
            panic!("not acquire")
        };
        assert_eq!(a.device, ["sim:field", "sim:field?ppm=87"]);
    }

    #[test]
    fn follower_channels_are_a_list_of_counts_refused_by_name() {
        let args = ["acquire", "sim:field", "sim:field?ppm=87", "sim:field", "--follower-channels", "4,1"];
        let Command::Acquire(a) = parse(&args).unwrap().command else { panic!("not acquire") };
        assert_eq!(a.follower_channels, [4, 1]);
        for (bad, says) in [
            ("0", "0 is out of range (1..=64 channels)"),
            ("65", "65 is out of range"),
            ("4,x", "\"x\" is not a channel count"),
        ] {
            let e = parse(&["acquire", "sim:field", "sim:field", "--follower-channels", bad]).unwrap_err();
            assert_eq!(e.exit_code(), exit::USAGE, "{bad}");
            assert!(
                e.to_string().contains("--follower-channels") && e.to_string().contains(says),
                "{bad}: {e}"
            );
        }
    }
}
