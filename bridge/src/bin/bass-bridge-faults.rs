//! `bass-bridge-faults`: the network suite's build of `bass-bridge`, the same code with one
//! more option, `--fault PLAN` (bridge/src/fault.rs), given before the command:
//! `bass-bridge-faults --fault drop=300 serve ...`. Built beside `bass-bridge` with the same
//! features (Zenoh is compiled once) and never installed.
#![forbid(unsafe_code)]

use clap::Parser;

#[derive(Parser)]
#[command(name = "bass-bridge-faults", version, about = "bass-bridge with test-only fault injection")]
struct Cli {
    /// Deterministic faults by sequence number: e.g. `drop=5,dup=7,reorder=9,delay=11`;
    /// `control-delay=MS` holds each forwarded control request.
    #[arg(long)]
    fault: Option<String>,
    /// Print the Zenoh password FROM presents to TO, derived from credentials FILE (one of
    /// FROM, TO must be FILE's identity): what the security case tries as a colleague would.
    #[arg(long, num_args = 3, value_names = ["FILE", "FROM", "TO"])]
    print_pair_password: Option<Vec<String>>,
    #[command(subcommand)]
    cmd: Option<bass_bridge::Cmd>,
}

fn main() {
    let cli = Cli::parse();
    if let Some([file, from, to]) = cli.print_pair_password.as_deref() {
        let pw = bass_bridge::credentials::Credentials::load(std::path::Path::new(file))
            .ok()
            .and_then(|c| c.pair_password(from, to));
        match pw {
            Some(pw) => println!("{pw}"),
            None => std::process::exit(3),
        }
        std::process::exit(0);
    }
    let Some(cmd) = cli.cmd else {
        eprintln!("bass-bridge-faults: give a command");
        std::process::exit(2);
    };
    match bass_bridge::fault::Faults::parse(cli.fault.as_deref()) {
        Ok(f) => bass_bridge::main_with(cmd, f),
        Err(e) => {
            eprintln!("bass-bridge-faults: {e:#}");
            std::process::exit(2);
        }
    }
}
