//! Exit codes of `bass` (documented in docs/broker.md) and the mapping of errors onto them.
//!
//! | code | meaning |
//! |------|---------|
//! | 0 | success (including a read that ended on a Stop or on its own limits, and a command whose stdout pipe closed: [`crate::out`]) |
//! | 1 | any other failure (a file, the port format, an unexpected reply) |
//! | 2 | usage error: a bad option or value, or a request the broker refused as invalid or not permitted (a window over `--max-port-bytes`, a port that does not fit in the port directory, a device its policy does not allow) |
//! | 3 | the broker cannot be reached (not running, socket missing, or it died) |
//! | 4 | device error: the broker could not open or configure the device |
//! | 5 | the acquisition being read ended on a device error (past `--max-outage`) |
//! | 6 | timeout: the broker did not answer, or no port appeared, within `--timeout` |
//!
//! The same table is in docs/broker.md; cli/tests/exit_codes.rs holds the two together and
//! produces each code with a real broker.

use std::fmt;

use bassport::Error;

/// Success.
pub const OK: i32 = 0;
/// Any other failure.
pub const FAILURE: i32 = 1;
/// Bad command line, or a request the broker refused as invalid (clap also exits with 2).
pub const USAGE: i32 = 2;
/// The broker cannot be reached.
pub const NO_BROKER: i32 = 3;
/// The broker could not open or configure the device.
pub const DEVICE: i32 = 4;
/// The acquisition being read ended on a device error.
pub const DEVICE_ENDED: i32 = 5;
/// The broker or the port did not answer in time.
pub const TIMEOUT: i32 = 6;

/// An error that carries its exit code.
#[derive(Debug)]
pub struct Exit {
    /// Exit code.
    pub code: i32,
    /// What to print.
    pub message: String,
}

impl Exit {
    /// An error exiting with `code`.
    pub fn new(code: i32, message: impl Into<String>) -> Exit {
        Exit { code, message: message.into() }
    }
}

impl fmt::Display for Exit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Exit {}

/// The exit code for `e`: the first [`Exit`] or library error in its chain decides.
pub fn code_of(e: &anyhow::Error) -> i32 {
    for cause in e.chain() {
        if let Some(x) = cause.downcast_ref::<Exit>() {
            return x.code;
        }
        if let Some(x) = cause.downcast_ref::<Error>() {
            return code_of_library(x);
        }
    }
    FAILURE
}

fn code_of_library(e: &Error) -> i32 {
    match e {
        Error::InvalidArgument(_) => USAGE,
        Error::NoBroker { .. } | Error::WriterGone { .. } => NO_BROKER,
        Error::Device { .. } => DEVICE_ENDED,
        Error::Timeout { .. } => TIMEOUT,
        Error::Io { source, .. } if source.kind() == std::io::ErrorKind::TimedOut => TIMEOUT,
        Error::Broker(m) if m.ends_with("[device]") => DEVICE,
        Error::Broker(m) if m.ends_with("[invalid-argument]") || m.ends_with("[permission]") => USAGE,
        _ => FAILURE,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn library_errors_map_to_distinct_codes() {
        let io = |k| Error::io("x", std::io::Error::from(k));
        let cases = [
            (Error::NoBroker { name: "a".into(), path: "/x".into(), source: io_err() }, NO_BROKER),
            (Error::Broker("no such device [device]".into()), DEVICE),
            (Error::Broker("nFramesPerChunk = 0 [invalid-argument]".into()), USAGE),
            (Error::Device { code: 2, message: "unplugged".into() }, DEVICE_ENDED),
            (io(std::io::ErrorKind::TimedOut), TIMEOUT),
            (Error::Corrupt("x".into()), FAILURE),
        ];
        for (e, code) in cases {
            let msg = e.to_string();
            assert_eq!(code_of(&anyhow::Error::from(e).context("while testing")), code, "{msg}");
        }
        assert_eq!(code_of(&anyhow::Error::from(Exit::new(TIMEOUT, "late"))), TIMEOUT);
    }

    fn io_err() -> std::io::Error {
        std::io::Error::from(std::io::ErrorKind::NotFound)
    }
}
