//! Tests that cannot run everywhere (they need root, `setpriv`, jackd) and other users.
//!
//! Such a test skips where it cannot run, saying why — but a skip must not pass where the
//! test could have run: with [`NO_SKIP_VAR`] set (CI: `.ci/run` sets it when it runs as
//! root with every tool installed), a test that would skip fails instead, naming the switch.

use std::ffi::OsStr;
use std::process::{Command, Output};

/// The switch: `BASS_TESTS_NO_SKIP=1` turns every skip into a failure.
pub const NO_SKIP_VAR: &str = "BASS_TESTS_NO_SKIP";

/// Whether skips are failures here ([`NO_SKIP_VAR`] set to anything but empty or `0`).
pub fn skips_forbidden() -> bool {
    std::env::var_os(NO_SKIP_VAR).is_some_and(|v| !v.is_empty() && v != "0")
}

/// Decides a test that needs something: `missing` is why it cannot run here (`None`: it
/// can). Returns `true` if the test must return at once (it prints `SKIPPED: <why>`);
/// panics instead if [`NO_SKIP_VAR`] is set.
///
/// ```no_run
/// # fn t() {
/// if bass_test_support::skip(bass_test_support::root_missing()) {
///     return;
/// }
/// # }
/// ```
pub fn skip(missing: Option<String>) -> bool {
    let Some(why) = missing else { return false };
    assert!(
        !skips_forbidden(),
        "this test cannot run here ({why}) but {NO_SKIP_VAR} is set: in CI a skip is a failure"
    );
    println!("SKIPPED: {why}");
    true
}

/// Whether this process runs as root.
pub fn is_root() -> bool {
    rustix::process::geteuid().is_root()
}

/// Why a root-only test cannot run here, or `None`.
pub fn root_missing() -> Option<String> {
    (!is_root()).then(|| "needs root".to_owned())
}

/// Why a test that runs commands as another user (root and `setpriv`) cannot run here, or
/// `None`.
pub fn impersonation_missing() -> Option<String> {
    root_missing().or_else(|| {
        let found = Command::new("setpriv").arg("--version").output().is_ok_and(|o| o.status.success());
        (!found).then(|| "needs setpriv (util-linux)".to_owned())
    })
}

/// `setpriv` options that run a command as uid and gid 65534 (nobody) with no other group.
pub const NOBODY: [&str; 3] = ["--reuid=65534", "--regid=65534", "--clear-groups"];

/// `setpriv` options that run a command as uid and gid 65534, member of group `gid` only.
pub fn nobody_in_group(gid: u32) -> [String; 3] {
    ["--reuid=65534".into(), "--regid=65534".into(), format!("--groups={gid}")]
}

/// `setpriv OPTIONS PROGRAM`: `program` run as the user `options` name (root only).
pub fn setpriv<S: AsRef<str>>(options: &[S], program: impl AsRef<OsStr>) -> Command {
    let mut c = Command::new("setpriv");
    c.args(options.iter().map(AsRef::as_ref)).arg(program);
    c
}

/// Runs `cmd ARGS` as uid 65534 ([`NOBODY`]) and returns what it printed and its status.
pub fn as_nobody(cmd: &str, args: &[&str]) -> Output {
    setpriv(&NOBODY, cmd).args(args).output().expect("run setpriv")
}
