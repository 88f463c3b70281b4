//! Writing to stdout and stderr the way Unix tools do on a closed pipe: `bass blocks | head -1`
//! ends quietly with exit 0 once `head` has its line.
//!
//! Rust ignores SIGPIPE, so a write to a pipe nobody reads fails with EPIPE, and `println!`
//! panics on it (exit 101). Every line `bass` prints goes through [`line()`] instead: EPIPE on
//! stdout becomes [`StdoutClosed`], which `main` turns into exit 0 without a message. Exit 0,
//! not death by SIGPIPE (141, as `cat` does), because the reader ends because its consumer has
//! what it wanted: `set -o pipefail` scripts such as `bass blocks --json | head -1 > first`
//! succeed, and a recording still finishes its file before saying so. SIGPIPE stays ignored,
//! so a broken control socket is still reported as the broker gone (exit 3). Other write errors
//! on stdout (a full disk behind `>`) are errors (exit 1). Notes on stderr ([`note_line`]) are best
//! effort: a closed stderr neither panics nor ends the command.

use std::fmt;
use std::io::{self, Write};

/// Stdout is a pipe whose reader is gone (EPIPE): the command ends quietly, exit 0.
#[derive(Debug)]
pub struct StdoutClosed;

impl fmt::Display for StdoutClosed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("stdout closed")
    }
}

impl std::error::Error for StdoutClosed {}

/// Whether `e` is (caused by) a closed stdout.
pub fn is_stdout_closed(e: &anyhow::Error) -> bool {
    e.chain().any(|c| c.is::<StdoutClosed>())
}

/// The error for a failed write to stdout.
pub fn stdout_error(e: io::Error) -> anyhow::Error {
    if e.kind() == io::ErrorKind::BrokenPipe {
        StdoutClosed.into()
    } else {
        anyhow::Error::new(e).context("writing to stdout")
    }
}

/// Writes `text` and a newline to stdout (flushed, so a pipe sees each line when it is made).
pub fn line(text: fmt::Arguments<'_>) -> anyhow::Result<()> {
    let mut out = io::stdout().lock();
    out.write_fmt(text).and_then(|()| out.write_all(b"\n")).and_then(|()| out.flush()).map_err(stdout_error)
}

/// Writes `bytes` to stdout as they are.
pub fn bytes(b: &[u8]) -> anyhow::Result<()> {
    let mut out = io::stdout().lock();
    out.write_all(b).and_then(|()| out.flush()).map_err(stdout_error)
}

/// Writes `text` and a newline to stderr, ignoring a failure (a note must not end a command).
pub fn note_line(text: fmt::Arguments<'_>) {
    let mut err = io::stderr().lock();
    let _ = err.write_fmt(text).and_then(|()| err.write_all(b"\n"));
}

/// `println!` that returns `anyhow::Result<()>`: `Err(StdoutClosed)` on a closed pipe.
macro_rules! outln {
    ($($arg:tt)*) => { $crate::out::line(format_args!($($arg)*)) };
}

/// `eprintln!` that never panics.
macro_rules! note {
    ($($arg:tt)*) => { $crate::out::note_line(format_args!($($arg)*)) };
}

pub(crate) use {note, outln};
