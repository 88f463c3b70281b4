//! Opening a broker's port and following it across acquisitions.
//!
//! An Acquire that interrupts a running acquisition first stops the old one (its port shows
//! Stopped for a moment) and then publishes a new port file (the old one shows Superseded).
//! A reader that sees Stopped therefore cannot tell from the port alone whether the
//! acquisition really ended: [`after_stop`] asks the broker. The broker handles one request
//! at a time, so a Status sent while an Acquire is being carried out is answered after it,
//! with the new epoch: no guessing, no timing.

use std::time::{Duration, Instant};

use anyhow::Result;
use bassclient::control::Client;
use bassclient::format::State;
use bassclient::{Error, Port};

use crate::exit::{self, Exit};

/// After how long a waiting command says that it waits.
pub const WAIT_NOTICE: Duration = Duration::from_secs(1);

/// Opens port `name`, retrying while it does not exist or is not initialised, for at most
/// `timeout`; says "waiting for the port…" on stderr once after [`WAIT_NOTICE`]. With
/// `newer_than`, a port of that epoch or older is not accepted (the file being replaced).
pub fn open_port(name: &str, timeout: Duration, newer_than: Option<u64>) -> Result<Port> {
    let t0 = Instant::now();
    let mut told = false;
    loop {
        let last_error = match Port::open(name) {
            Ok(p) if newer_than.map_or(true, |e| p.epoch() > e) => return Ok(p),
            Ok(p) => format!("port {name} still holds epoch {}", p.epoch()),
            Err(e @ (Error::NotFound { .. } | Error::NotReady)) => e.to_string(),
            Err(e) => return Err(e.into()),
        };
        let waited = t0.elapsed();
        if waited >= timeout {
            return Err(Exit::new(
                exit::TIMEOUT,
                format!(
                    "no port {name} after {:.1} s ({last_error}); start an acquisition with `bass --name {name} acquire DEVICE` (see `bass devices`), or raise --timeout",
                    waited.as_secs_f64()
                ),
            )
            .into());
        }
        if !told && waited >= WAIT_NOTICE {
            eprintln!("bass: waiting for the port {name}… (up to {:.0} s, --timeout)", timeout.as_secs_f64());
            told = true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// What a Stopped port means.
#[derive(Debug, PartialEq, Eq)]
pub enum AfterStop {
    /// A new acquisition replaced this one: reopen the port.
    Restarted,
    /// The acquisition really stopped (or the broker shut down).
    Stopped,
}

/// Decides what the Stopped state of `port` means by asking broker `name` (see the module
/// documentation). A broker that cannot be reached has shut down: a real stop.
pub fn after_stop(name: &str, port: &Port, timeout: Duration) -> Result<AfterStop> {
    if port.info()?.state == Some(State::Superseded) {
        return Ok(AfterStop::Restarted);
    }
    let status = match Client::connect(name) {
        Ok(mut c) => {
            c.set_timeout(timeout)?;
            c.status()
        }
        Err(e) => Err(e),
    };
    match status {
        Ok(s) if s.epoch > port.epoch() => Ok(AfterStop::Restarted),
        Ok(_) => Ok(if port.info()?.state == Some(State::Superseded) {
            AfterStop::Restarted
        } else {
            AfterStop::Stopped
        }),
        Err(Error::NoBroker { .. }) => Ok(AfterStop::Stopped),
        Err(e) => Err(e.into()),
    }
}
