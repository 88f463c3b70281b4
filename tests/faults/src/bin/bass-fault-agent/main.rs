//! The fault agent: the child processes of the fault suite (a pattern writer, pattern readers
//! of several kinds, victims to kill, a process that tries to write through a reader's
//! mapping, a reader hammered while its port shrinks). Tests start it, stop it, kill it and
//! read its `ready` / `READ` / `RESULT` lines.
//!
//! ```text
//! bass-fault-agent writer  --port P [--channels 2 --nfpc 64 --ncop 8 --rate 48000]
//!                          [--pace-us U] [--chunks K | --seconds S] [--wait-go]
//! bass-fault-agent reader  --port P --mode copy|wait|view --n N [--pause-us U] [--log-loss]
//! bass-fault-agent stepped --port P --n N          (one read per "read" line on stdin)
//! bass-fault-agent victim  --port P --mode read|wait
//! bass-fault-agent poke    --port P                (writes through its read-only mapping)
//! bass-fault-agent shrink-victim --port P          (library calls until stdin closes)
//! bass-fault-agent try-open --port P               (reports whether it may open / write)
//! bass-fault-agent try-open --name N               (opens by name: a memfd port through the broker)
//! bass-fault-agent control-victim --socket S --name N  (status requests forever)
//! bass-fault-agent follow --port P --n N --expect zero|pattern  (across epochs, until stdin closes)
//! bass-fault-agent hold-connections --socket S --name N --n K  (holds them until stdin closes)
//! bass-fault-agent pin-loop --socket S --name N [--device D --rate R --nfpc F --ncop C
//!                           --channels CH] --rounds K  (Acquire and keep each new port mapped)
//! ```
//!
//! Wherever a port is read, `--fd N` (an inherited descriptor, e.g. of a memfd port) or
//! `--name N` (`Port::open`, in $BASS_RUNTIME_DIR) may stand for `--port P`.
//!
//! Arguments are parsed with clap (`bass-fault-agent ROLE --help`); a bad value is an error
//! naming the option, exit status 2. Output lines go through `say!`: if the test stops
//! reading, the agent ends quietly with status 0 instead of panicking on EPIPE.
#![deny(unsafe_code)]

use std::fmt;
use std::io::{BufRead, ErrorKind, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use bassport::{Error, Port};
use clap::{Args, Parser, Subcommand};

/// Prints one line for the test on stdout.
macro_rules! say {
    ($($arg:tt)*) => {
        say(format_args!($($arg)*))
    };
}

mod broker;
mod readers;
mod victims;
#[allow(unsafe_code)] // clock_nanosleep(TIMER_ABSTIME)
mod writer;

use broker::{control_victim, hold_connections, pin_loop, BrokerArgs, HoldArgs, PinArgs};
use readers::{follow, reader, stepped, FollowArgs, ReaderArgs, SteppedArgs};
use victims::{poke, shrink_victim, try_open, victim, VictimArgs};
use writer::{writer, WriterArgs};

/// The child processes of the bass fault suite.
#[derive(Parser)]
#[command(name = "bass-fault-agent")]
struct Cli {
    #[command(subcommand)]
    role: Role,
}

#[derive(Subcommand)]
enum Role {
    /// Publish the pattern signal into a new port.
    Writer(WriterArgs),
    /// Read the pattern until the writer stops; report the accounting.
    Reader(ReaderArgs),
    /// One read per `read` line on stdin, reported as a `READ` line.
    Stepped(SteppedArgs),
    /// Read or wait forever, to be killed mid-call.
    Victim(VictimArgs),
    /// Store through the read-only mapping (must fault).
    Poke(PortArg),
    /// Call every size-dependent library function until stdin closes.
    ShrinkVictim(PortArg),
    /// Report whether this process may open the port for reading and for writing.
    TryOpen(PortArg),
    /// Send status requests forever, to be killed mid-request.
    ControlVictim(BrokerArgs),
    /// Follow the port across acquisitions until stdin closes.
    Follow(FollowArgs),
    /// Open control connections and hold the served ones until stdin closes.
    HoldConnections(HoldArgs),
    /// Acquire and keep each new port mapped, round after round.
    PinLoop(PinArgs),
}

#[derive(Args)]
#[group(required = true, multiple = false)]
struct PortArg {
    /// The port file.
    #[arg(long)]
    port: Option<PathBuf>,
    /// An inherited descriptor of the port (close-on-exec cleared), e.g. of a memfd port.
    #[arg(long)]
    fd: Option<i32>,
    /// A port name, opened with `Port::open` (a memfd port through its broker).
    #[arg(long)]
    name: Option<String>,
}

impl PortArg {
    /// The port file, for the roles that need a path.
    fn path(&self) -> &Path {
        self.port.as_deref().unwrap_or_else(|| {
            eprintln!("bass-fault-agent: this role needs --port PATH");
            std::process::exit(2)
        })
    }
}

fn main() {
    match Cli::parse().role {
        Role::Writer(a) => writer(&a),
        Role::Reader(a) => reader(&a),
        Role::Stepped(a) => stepped(&a),
        Role::Victim(a) => victim(&a),
        Role::Poke(a) => poke(&a),
        Role::ShrinkVictim(a) => shrink_victim(&a),
        Role::TryOpen(a) => try_open(&a),
        Role::ControlVictim(a) => control_victim(&a),
        Role::Follow(a) => follow(&a),
        Role::HoldConnections(a) => hold_connections(&a),
        Role::PinLoop(a) => pin_loop(&a),
    }
}

/// Writes `line` and a newline to stdout and flushes. A test that has stopped reading (the
/// pipe's read end is closed: EPIPE) leaves no one to report to, so the agent ends quietly
/// with status 0 rather than panicking; any other write error is status 1 with a message.
fn say(line: fmt::Arguments) {
    let mut out = std::io::stdout().lock();
    if let Err(e) = writeln!(out, "{line}").and_then(|()| out.flush()) {
        if e.kind() == ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("bass-fault-agent: writing to stdout: {e}");
        std::process::exit(1);
    }
}

/// A flag set when stdin reaches EOF or a "stop" line.
fn stdin_stop_flag() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    std::thread::spawn(move || {
        let stdin = std::io::stdin();
        let mut line = String::new();
        loop {
            line.clear();
            match stdin.lock().read_line(&mut line) {
                Ok(0) | Err(_) => break,
                Ok(_) if line.trim() == "stop" => break,
                Ok(_) => {}
            }
        }
        f.store(true, Ordering::Relaxed);
    });
    flag
}

#[allow(unsafe_code)] // adopts the port descriptor the test passed
fn open(a: &PortArg) -> Port {
    if let Some(fd) = a.fd {
        use std::os::fd::FromRawFd;
        // SAFETY: the test passed us this inherited descriptor (close-on-exec cleared) for us
        // alone; nothing else in this process owns or closes it.
        let owned = unsafe { std::os::fd::OwnedFd::from_raw_fd(fd) };
        return Port::from_fd(owned, "inherited").unwrap_or_else(|e| panic!("port from fd {fd}: {e}"));
    }
    if let Some(name) = &a.name {
        return Port::open(name).unwrap_or_else(|e| panic!("open port {name}: {e}"));
    }
    let path = a.path();
    let end = Instant::now() + Duration::from_secs(10);
    loop {
        match Port::open_path(path) {
            Ok(p) => return p,
            Err(Error::NotFound { .. } | Error::NotReady) if Instant::now() < end => {
                std::thread::sleep(Duration::from_millis(2))
            }
            Err(e) => panic!("open {}: {e}", path.display()),
        }
    }
}
