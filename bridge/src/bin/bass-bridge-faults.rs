//! `bass-bridge-faults`: the network suite's build of `bass-bridge`, the same code with one
//! more option, `--fault PLAN` (bridge/src/fault.rs), given before the command:
//! `bass-bridge-faults --fault drop=300 serve ...`. Built beside `bass-bridge` with the same
//! features (Zenoh is compiled once) and never installed.

use clap::Parser;

#[derive(Parser)]
#[command(name = "bass-bridge-faults", version, about = "bass-bridge with test-only fault injection")]
struct Cli {
    /// Deterministic faults by sequence number: e.g. `drop=5,dup=7,reorder=9,delay=11`;
    /// `control-delay=MS` holds each forwarded control request.
    #[arg(long)]
    fault: Option<String>,
    #[command(subcommand)]
    cmd: bass_bridge::Cmd,
}

fn main() {
    let cli = Cli::parse();
    match bass_bridge::fault::Faults::parse(cli.fault.as_deref()) {
        Ok(f) => bass_bridge::main_with(cli.cmd, f),
        Err(e) => {
            eprintln!("bass-bridge-faults: {e:#}");
            std::process::exit(2);
        }
    }
}
