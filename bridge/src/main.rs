//! `bass-bridge`, the installed binary: `serve` and `mirror` (docs/network.md).
#![forbid(unsafe_code)]

use clap::Parser;

#[derive(Parser)]
#[command(name = "bass-bridge", version, about = "bass across computers (Zenoh) and to iceoryx2")]
struct Cli {
    #[command(subcommand)]
    cmd: bass_bridge::Cmd,
}

fn main() {
    let cli = Cli::parse();
    bass_bridge::main_with(cli.cmd, bass_bridge::fault::Faults::default())
}
