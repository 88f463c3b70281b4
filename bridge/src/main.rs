//! `bass-bridge`: a bass port across computers over Zenoh (`serve` on the capturing machine,
//! `mirror` on the reading one), and an iceoryx2 export of its chunks. docs/network.md.

mod clock;
mod control;
mod fault;
#[cfg(feature = "iceoryx2")]
mod iox;
mod mirror;
mod net;
mod serve;
mod wire;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "bass-bridge", version, about = "bass across computers (Zenoh) and to iceoryx2")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Publish a local port's chunks (capture side).
    Serve(serve::ServeOpts),
    /// Write a local replica port of a remote source (reading side).
    Mirror(mirror::MirrorOpts),
}

fn main() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("BASS_LOG")
                .unwrap_or_else(|_| "info,zenoh=error".into()),
        )
        .with_writer(std::io::stderr)
        // Colour codes only on a terminal: logs are mostly read from files and journals.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let cli = Cli::parse();
    let r = match cli.cmd {
        Cmd::Serve(o) => serve::run(o),
        Cmd::Mirror(o) => mirror::run(o),
    };
    if let Err(e) = r {
        eprintln!("bass-bridge: {e:#}");
        std::process::exit(1);
    }
}
