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
use bassport::control::Client;
use bassport::format::State;
use bassport::{Error, Port};

use crate::exit::{self, Exit};
use crate::out::note;

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
            note!("bass: waiting for the port {name}… (up to {:.0} s, --timeout)", timeout.as_secs_f64());
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

/// A pause a reader rides through: the acquisition ended on a device error or its writer is
/// gone, which a replica's link outage, a broker restarted by its service manager after the
/// restart grace, or a device that comes back all end by themselves (the port goes on, the
/// frames missed come as GAP frames or loss). Said once when it begins and once when frames
/// flow again; only a bound the user set (`--max-outage`) ends the reader.
#[derive(Debug)]
pub struct Outage {
    since: Option<(Instant, String)>,
    max: Option<Duration>,
}

/// How long a reader sleeps between looks at a paused port (its waits return at once).
pub const OUTAGE_POLL: Duration = Duration::from_millis(50);

impl Outage {
    /// No outage yet; `max_s` is `--max-outage` (None: wait for ever).
    pub fn new(max_s: Option<f64>) -> Outage {
        Outage { since: None, max: max_s.map(Duration::from_secs_f64) }
    }

    /// A wait ended on `e` (a device error or a gone writer; anything else is returned as the
    /// error it is). The first time: Ok(Some(what to say)); later: Ok(None) after a short
    /// sleep; past `--max-outage`: the exit the error stands for, naming the bound.
    pub fn pause(&mut self, e: Error, name: &str) -> Result<Option<String>> {
        let (code, why) = match &e {
            Error::Device { code, message } => {
                (exit::DEVICE_ENDED, format!("device error (code {code}): {message}"))
            }
            Error::WriterGone { .. } => (exit::NO_BROKER, e.to_string()),
            _ => return Err(e.into()),
        };
        match &self.since {
            None => {
                self.since = Some((Instant::now(), why.clone()));
                let bound = match self.max {
                    Some(m) => format!("for up to {:.1} s (--max-outage)", m.as_secs_f64()),
                    None => "(Ctrl-C ends; --max-outage SECONDS bounds the wait)".to_owned(),
                };
                Ok(Some(format!(
                    "-- the acquisition paused: {why}; waiting for it to go on {bound}; see `bass --name {name} status`"
                )))
            }
            Some((t0, _)) => {
                if self.max.is_some_and(|m| t0.elapsed() >= m) {
                    return Err(Exit::new(
                        code,
                        format!("{why}: no frames for {:.1} s (--max-outage)", t0.elapsed().as_secs_f64()),
                    )
                    .into());
                }
                std::thread::sleep(OUTAGE_POLL);
                Ok(None)
            }
        }
    }

    /// Frames flow again: Some(what to say) if an outage ended (its length and cause).
    pub fn resumed(&mut self) -> Option<String> {
        let (t0, why) = self.since.take()?;
        Some(format!(
            "-- the acquisition goes on after {:.2} s ({why}); the frames missed are counted as gap or loss",
            t0.elapsed().as_secs_f64()
        ))
    }

    /// Whether an outage is going on.
    pub fn active(&self) -> bool {
        self.since.is_some()
    }
}
