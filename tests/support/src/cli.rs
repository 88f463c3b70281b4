//! The `bass` command line bound to a test's broker.

use std::process::{Command, Output};

use crate::{bass_bin, Bassd};

/// A `bass` command line bound to broker `b` (its name and runtime directory).
pub fn bass_cmd(b: &Bassd, args: &[&str]) -> Command {
    let mut c = Command::new(bass_bin());
    c.arg("--name").arg(&b.name).args(args).env("BASS_RUNTIME_DIR", &b.dir);
    c
}

/// Runs `bass` against broker `b` and returns what it printed and its exit status.
pub fn bass(b: &Bassd, args: &[&str]) -> Output {
    bass_cmd(b, args).output().expect("run bass")
}

/// stdout then stderr of a finished command, as text.
pub fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}
