//! Helpers shared by the fault and abuse suite: spawning the fault agent
//! (`bass-fault-agent`, the child processes the tests kill, stop and starve), reading
//! their result lines, counting file descriptors and resident memory through /proc, and
//! the pattern check every delivered sample goes through. The rig the suite shares with the
//! broker's tests (temporary directories, bassd, jackd, bounded waits) is `bass-test-support`.
//!
//! Every test prints its measured figures as lines starting with `FIGURE`, which
//! `tests/faults/run.sh` collects into one summary.
#![forbid(unsafe_code)]

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Duration;

use basskit::testsignal::pattern_expected;

/// Prints one measured figure of item `item` (collected by run.sh).
#[macro_export]
macro_rules! figure {
    ($item:expr, $($arg:tt)*) => {
        println!("FIGURE item {}: {}", $item, format!($($arg)*))
    };
}

/// Path of the fault agent binary (built by cargo alongside the tests).
pub fn agent_path() -> PathBuf {
    bass_test_support::bin_path("bass-fault-agent", "BASS_FAULT_AGENT")
}

/// Whether the suite runs as root (the other-uid checks need setpriv as root).
pub fn is_root() -> bool {
    bass_test_support::is_root()
}

/// The group the permission tests configure: 4242 as root (any gid may be given), else the
/// caller's own group (the only one a non-root process may chown to for sure).
pub fn test_group() -> u32 {
    if is_root() {
        4242
    } else {
        rustix::process::getegid().as_raw()
    }
}

/// A running agent process with line-oriented stdout.
pub struct Agent {
    /// The child.
    pub child: Child,
    out: BufReader<ChildStdout>,
    /// Lines read so far.
    pub lines: Vec<String>,
}

impl Agent {
    /// Spawns the agent with `args` (first the role).
    pub fn spawn(args: &[&str]) -> Agent {
        Agent::spawn_env(args, &[])
    }

    /// A pattern writer creating port `port` (`nfpc` frames per chunk, `ncop` chunks on the
    /// port, then `extra` options: pacing, length), returned once the port exists (its
    /// `ready` line) and held there until the test sends `go` (so readers can start first).
    pub fn writer_held(port: &str, nfpc: u32, ncop: u32, extra: &[&str]) -> Agent {
        let (nfpc, ncop) = (nfpc.to_string(), ncop.to_string());
        let mut args = vec!["writer", "--port", port, "--nfpc", &nfpc, "--ncop", &ncop];
        args.extend_from_slice(extra);
        args.push("--wait-go");
        let mut w = Agent::spawn(&args);
        w.expect_line("ready");
        w
    }

    /// Spawns the agent with `args` and extra environment variables.
    pub fn spawn_env(args: &[&str], env: &[(&str, &str)]) -> Agent {
        let mut cmd = Command::new(agent_path());
        cmd.args(args);
        for (k, v) in env {
            cmd.env(k, v);
        }
        Agent::spawn_cmd(cmd)
    }

    /// Spawns the agent as another user: `setpriv SETPRIV... agent ARGS` (root only).
    pub fn spawn_setpriv(setpriv: &[&str], args: &[&str]) -> Agent {
        let mut cmd = Command::new("setpriv");
        cmd.args(setpriv).arg(agent_path()).args(args);
        Agent::spawn_cmd(cmd)
    }

    fn spawn_cmd(mut cmd: Command) -> Agent {
        cmd.stdin(Stdio::piped()).stdout(Stdio::piped()).stderr(Stdio::inherit());
        let mut child = cmd.spawn().expect("spawn bass-fault-agent");
        let out = BufReader::new(child.stdout.take().expect("stdout"));
        Agent { child, out, lines: Vec::new() }
    }

    /// Process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Reads lines until one starts with `prefix`; returns it (panics on EOF).
    pub fn expect_line(&mut self, prefix: &str) -> String {
        loop {
            let mut l = String::new();
            let n = self.out.read_line(&mut l).expect("read agent stdout");
            assert!(
                n > 0,
                "agent {} exited before printing {prefix:?}; output: {:?}",
                self.pid(),
                self.lines
            );
            let l = l.trim_end().to_owned();
            self.lines.push(l.clone());
            if l.starts_with(prefix) {
                return l;
            }
        }
    }

    /// Sends one line to the agent's stdin.
    pub fn send(&mut self, line: &str) {
        let stdin = self.child.stdin.as_mut().expect("stdin");
        writeln!(stdin, "{line}").expect("write agent stdin");
        stdin.flush().expect("flush agent stdin");
    }

    /// Closes the agent's stdin (agents that run "until stdin closes" then finish).
    pub fn close_stdin(&mut self) {
        drop(self.child.stdin.take());
    }

    /// Sends a signal.
    pub fn signal(&self, sig: libc::c_int) {
        bass_test_support::send_signal(self.pid(), sig);
    }

    /// Reads to EOF and waits; returns the exit status and every line.
    pub fn finish(mut self) -> (std::process::ExitStatus, Vec<String>) {
        let mut rest = String::new();
        while self.out.read_line(&mut rest).unwrap_or(0) > 0 {
            self.lines.push(rest.trim_end().to_owned());
            rest.clear();
        }
        drop(self.child.stdin.take());
        let status = self.child.wait().expect("wait agent");
        (status, std::mem::take(&mut self.lines))
    }

    /// Waits for the `RESULT` line, then for the exit; asserts success; returns the fields.
    pub fn result(self) -> Fields {
        let pid = self.pid();
        let (status, lines) = self.finish();
        assert!(status.success(), "agent {pid} failed: {status}; output: {lines:?}");
        let line = lines
            .iter()
            .rev()
            .find(|l| l.starts_with("RESULT"))
            .unwrap_or_else(|| panic!("agent {pid} printed no RESULT line; output: {lines:?}"));
        Fields::parse(line)
    }
}

impl Drop for Agent {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// Runs `setpriv OPTIONS bass-fault-agent try-open PORT_ARGS` (root only: the permission
/// probe as another user, e.g. [`bass_test_support::NOBODY`]) with extra environment; the
/// fields of its `RESULT` line (panics if it printed none).
pub fn try_open_as<S: AsRef<str>>(options: &[S], port_args: &[&str], env: &[(&str, &Path)]) -> Fields {
    let out = bass_test_support::setpriv(options, agent_path())
        .arg("try-open")
        .args(port_args)
        .envs(env.iter().copied())
        .output()
        .expect("run setpriv");
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().find(|l| l.starts_with("RESULT")).unwrap_or_else(|| {
        let opts: Vec<&str> = options.iter().map(AsRef::as_ref).collect();
        panic!("no RESULT from try-open as {opts:?}: {text} {}", String::from_utf8_lossy(&out.stderr))
    });
    Fields::parse(line)
}

/// `key=value` fields of a result line.
#[derive(Clone, Debug)]
pub struct Fields(pub BTreeMap<String, String>, pub String);

impl Fields {
    /// Parses `RESULT a=1 b=2 ...`.
    pub fn parse(line: &str) -> Fields {
        let map = line
            .split_whitespace()
            .filter_map(|kv| kv.split_once('='))
            .map(|(k, v)| (k.to_owned(), v.to_owned()))
            .collect();
        Fields(map, line.to_owned())
    }

    /// A numeric field (panics if missing).
    pub fn u(&self, key: &str) -> u64 {
        self.0
            .get(key)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("field {key} missing or not a number in {:?}", self.1))
    }

    /// A text field (panics if missing).
    pub fn s(&self, key: &str) -> &str {
        self.0.get(key).map(String::as_str).unwrap_or_else(|| panic!("field {key} missing in {:?}", self.1))
    }
}

/// Number of open file descriptors of `pid`.
pub fn fd_count(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd")).map(|d| d.count()).unwrap_or(0)
}

/// Targets of the open file descriptors of `pid` (sorted), e.g. `socket:[123]`, paths.
pub fn fd_targets(pid: u32) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .map(|d| {
            d.filter_map(|e| e.ok())
                .filter_map(|e| std::fs::read_link(e.path()).ok())
                .map(|p| p.to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// A `kB` field of /proc/PID/status (`VmRSS`, `RssAnon`, ...).
pub fn status_kb(pid: u32, field: &str) -> u64 {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    text.lines()
        .find_map(|l| l.strip_prefix(field).and_then(|r| r.strip_prefix(':')))
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

/// The syscall `pid` is blocked in (first field of /proc/PID/syscall), or "running".
pub fn current_syscall(pid: u32) -> String {
    std::fs::read_to_string(format!("/proc/{pid}/syscall"))
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_owned))
        .unwrap_or_else(|| "?".into())
}

/// Counts samples of frames `first..first+frames` that differ from the pattern signal.
pub fn count_corrupted(first: u64, frames: usize, bufs: &[Vec<i32>]) -> u64 {
    let mut bad = 0;
    for (c, buf) in bufs.iter().enumerate() {
        for (i, &s) in buf[..frames].iter().enumerate() {
            if s != pattern_expected(first + i as u64, c as u32) {
                bad += 1;
            }
        }
    }
    bad
}

/// Median and maximum of durations (sorted copy).
pub fn median_max(v: &[Duration]) -> (Duration, Duration) {
    if v.is_empty() {
        return (Duration::ZERO, Duration::ZERO);
    }
    let mut s = v.to_vec();
    s.sort();
    (s[s.len() / 2], s[s.len() - 1])
}

/// The PRNG of the randomised tests (fastrand's, seeded with [`seed`], so that a run is
/// reproducible from its printed seed).
pub use fastrand::Rng;

/// The seed for randomised tests: `$BASS_FAULTS_SEED`, else the clock.
pub fn seed() -> u64 {
    std::env::var("BASS_FAULTS_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or_else(|| {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(1)
    })
}

/// A duration from the environment in seconds (for CI-tunable run lengths), else `default`.
pub fn env_secs(var: &str, default: u64) -> u64 {
    std::env::var(var).ok().and_then(|s| s.parse().ok()).unwrap_or(default)
}
