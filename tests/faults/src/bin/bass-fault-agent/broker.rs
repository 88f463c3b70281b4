//! The control-socket roles: connections held open, a status loop to kill, and the
//! Acquire-and-pin loop.

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::Duration;

use bassport::Port;
use clap::Args;

use super::*;

#[derive(Args)]
pub(super) struct BrokerArgs {
    /// The broker's control socket.
    #[arg(long)]
    socket: PathBuf,
    /// The broker's name.
    #[arg(long, default_value = "default")]
    name: String,
}

#[derive(Args)]
pub(super) struct HoldArgs {
    #[command(flatten)]
    broker: BrokerArgs,
    /// Connections to open.
    #[arg(long, default_value_t = 1)]
    n: u64,
}

#[derive(Args)]
pub(super) struct PinArgs {
    #[command(flatten)]
    broker: BrokerArgs,
    #[arg(long, default_value = "sim:silence")]
    device: String,
    #[arg(long, default_value_t = 48000)]
    rate: u32,
    #[arg(long, default_value_t = 480)]
    nfpc: u32,
    #[arg(long, default_value_t = 100)]
    ncop: u32,
    #[arg(long, default_value_t = 2)]
    channels: u32,
    /// Acquire-and-keep rounds.
    #[arg(long, default_value_t = 10)]
    rounds: u64,
}

/// Opens `--n` control connections, asks each for the status, and holds the ones the broker
/// served until stdin closes; prints `held K refused R last_refusal=TEXT` first.
pub(super) fn hold_connections(a: &HoldArgs) {
    let (socket, name) = (&a.broker.socket, &a.broker.name);
    let mut held = Vec::new();
    let (mut refused, mut last) = (0, String::new());
    for _ in 0..a.n {
        match bassport::control::Client::connect_path(socket, name).and_then(|mut c| c.status().map(|_| c)) {
            Ok(c) => held.push(c),
            Err(e) => {
                refused += 1;
                last = e.to_string().replace(' ', "_");
            }
        }
    }
    say!("held {} refused {refused} last_refusal={last}", held.len());
    let stop = stdin_stop_flag();
    while !stop.load(Ordering::Acquire) {
        std::thread::sleep(Duration::from_millis(20));
    }
    say!("RESULT held={} refused={refused}", held.len());
}

/// Connects to a broker's control socket and sends status requests forever, to be
/// SIGKILLed mid-request.
pub(super) fn control_victim(a: &BrokerArgs) {
    let mut c = bassport::control::Client::connect_path(&a.socket, &a.name).expect("connect");
    say!("ready pid={}", std::process::id());
    loop {
        let _ = c.status();
    }
}

/// Acquire, open the new port and keep it mapped, `--rounds` times; prints
/// one line per round (`ROUND i ok epoch=E` or `ROUND i refused ...`), then `RESULT` and
/// holds every mapping until stdin closes.
pub(super) fn pin_loop(a: &PinArgs) {
    let mut c = bassport::control::Client::connect_path(&a.broker.socket, &a.broker.name).expect("connect");
    let req = bassport::control::AcquireRequest {
        device: a.device.clone(),
        sample_rate: a.rate,
        frames_per_chunk: a.nfpc,
        chunks_on_port: a.ncop,
        channels: a.channels,
        format: None,
        followers: Vec::new(),
    };
    let mut held = Vec::new();
    let (mut ok, mut refused) = (0, 0);
    for i in 0..a.rounds {
        match c.acquire(&req) {
            Ok(acq) => {
                ok += 1;
                held.push(Port::open_path(&acq.port).expect("open the new port"));
                say!("ROUND {i} ok epoch={}", acq.epoch);
            }
            Err(e) => {
                refused += 1;
                say!("ROUND {i} refused {}", e.to_string().replace('\n', " "));
            }
        }
    }
    say!("RESULT acquired={ok} refused={refused} held={}", held.len());
    let stop = stdin_stop_flag();
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(10));
    }
    drop(held);
}
