//! Helpers shared by the fault and abuse suite (issue 5): spawning the fault agent
//! (`bass-fault-agent`, the child processes the tests kill, stop and starve), reading
//! their result lines, counting file descriptors and resident memory through /proc,
//! private runtime directories, and the pattern check every delivered sample goes through.
//!
//! Every test prints its measured figures as lines starting with `FIGURE`, which
//! `tests/faults/run.sh` collects into one summary.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use bassclient::testsignal::pattern_expected;

/// Prints one measured figure of item `item` (collected by run.sh).
#[macro_export]
macro_rules! figure {
    ($item:expr, $($arg:tt)*) => {
        println!("FIGURE item {}: {}", $item, format!($($arg)*))
    };
}

/// A private directory under /dev/shm (real shared memory), removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    /// Creates `/dev/shm/bass-faults-<tag>-<pid>-<n>`.
    pub fn new(tag: &str) -> TempDir {
        static N: AtomicU64 = AtomicU64::new(0);
        let base: PathBuf =
            if Path::new("/dev/shm").is_dir() { "/dev/shm".into() } else { std::env::temp_dir() };
        let dir = base.join(format!(
            "bass-faults-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("create temp dir");
        TempDir(dir)
    }

    /// A path inside the directory.
    pub fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    /// Names of the files in the directory, sorted.
    pub fn entries(&self) -> Vec<String> {
        list_dir(&self.0)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Names of the files in `dir`, sorted.
pub fn list_dir(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| rd.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

/// Path of the fault agent binary (built by cargo alongside the tests).
pub fn agent_path() -> PathBuf {
    bin_path("bass-fault-agent", "BASS_FAULT_AGENT")
}

/// Path of a workspace binary (`bassd`, `bass`, the agent): `$env_var` if set, else next to
/// the running test (integration tests live in target/<profile>/deps, binaries one level up).
/// The broker binaries are built by `cargo build --release --workspace` (make test-faults).
pub fn bin_path(name: &str, env_var: &str) -> PathBuf {
    if let Some(p) = std::env::var_os(env_var) {
        return p.into();
    }
    let exe = std::env::current_exe().expect("current exe");
    let dir = exe.parent().expect("exe dir");
    for cand in [dir.join(name), dir.parent().unwrap_or(dir).join(name)] {
        if cand.is_file() {
            return cand;
        }
    }
    panic!("{name} not found next to {} (build the workspace first, or set {env_var})", exe.display())
}

/// A running `bassd` with its own runtime directory, killed on drop.
pub struct Bassd {
    /// The broker process.
    pub child: Option<Child>,
    /// Its runtime directory (`$BASS_RUNTIME_DIR`).
    pub dir: PathBuf,
    /// Broker name.
    pub name: String,
}

impl Bassd {
    /// Starts `bassd --name NAME --rt-priority 0 ARGS` in `dir` and waits until its control
    /// socket answers a status request (guarded by a generous 20 s).
    pub fn start(dir: &Path, name: &str, args: &[&str], env: &[(&str, &str)]) -> Bassd {
        let mut cmd = Command::new(bin_path("bassd", "BASS_BASSD"));
        cmd.args(["--name", name, "--rt-priority", "0"]).args(args);
        cmd.env("BASS_RUNTIME_DIR", dir).env("BASS_LOG", "error");
        for (k, v) in env {
            cmd.env(k, v);
        }
        cmd.stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::null());
        let child = cmd.spawn().expect("spawn bassd");
        let mut b = Bassd { child: Some(child), dir: dir.to_owned(), name: name.to_owned() };
        let ok = wait_until(Duration::from_secs(20), || {
            if let Some(st) = b.child.as_mut().and_then(|c| c.try_wait().ok().flatten()) {
                panic!("bassd exited during start-up: {st}");
            }
            b.try_client().and_then(|mut c| c.status()).is_ok()
        });
        assert!(ok, "bassd did not answer within 20 s");
        b
    }

    /// Process id.
    pub fn pid(&self) -> u32 {
        self.child.as_ref().map(|c| c.id()).unwrap_or(0)
    }

    /// Control socket path.
    pub fn socket(&self) -> PathBuf {
        self.dir.join(format!("bass-{}.sock", self.name))
    }

    /// Port file path.
    pub fn port_path(&self) -> PathBuf {
        self.dir.join(format!("bass-{}.port", self.name))
    }

    /// A control client, if the broker answers.
    pub fn try_client(&self) -> bassclient::Result<bassclient::control::Client> {
        bassclient::control::Client::connect_path(&self.socket(), &self.name)
    }

    /// A control client (panics if the broker does not answer).
    pub fn client(&self) -> bassclient::control::Client {
        self.try_client().expect("connect to bassd")
    }

    /// Sends `sig` and reaps the process.
    pub fn kill(&mut self, sig: libc::c_int) {
        if let Some(mut c) = self.child.take() {
            // SAFETY: kill(2) on our own child.
            unsafe { libc::kill(c.id() as libc::pid_t, sig) };
            let _ = c.wait();
        }
    }
}

impl Drop for Bassd {
    fn drop(&mut self) {
        if let Some(c) = self.child.as_ref() {
            // SAFETY: kill(2) on our own child; SIGTERM lets bassd remove its socket.
            unsafe { libc::kill(c.id() as libc::pid_t, libc::SIGTERM) };
            let end = Instant::now() + Duration::from_secs(5);
            while Instant::now() < end {
                if let Some(c) = self.child.as_mut() {
                    if c.try_wait().ok().flatten().is_some() {
                        self.child = None;
                        return;
                    }
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        self.kill(libc::SIGKILL);
    }
}

/// Whether the suite runs as root (the other-uid checks need setpriv as root).
pub fn is_root() -> bool {
    // SAFETY: geteuid cannot fail.
    unsafe { libc::geteuid() == 0 }
}

/// The group the permission tests configure: 4242 as root (any gid may be given), else the
/// caller's own group (the only one a non-root process may chown to for sure).
pub fn test_group() -> u32 {
    if is_root() {
        4242
    } else {
        // SAFETY: getegid cannot fail.
        unsafe { libc::getegid() }
    }
}

/// An Acquire request.
pub fn acquire_req(
    device: &str,
    rate: u32,
    nfpc: u32,
    ncop: u32,
    channels: u32,
) -> bassclient::control::AcquireRequest {
    bassclient::control::AcquireRequest {
        device: device.into(),
        sample_rate: rate,
        frames_per_chunk: nfpc,
        chunks_on_port: ncop,
        channels,
        format: None,
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
        // SAFETY: kill(2) on our own child's pid; no memory is involved.
        unsafe { libc::kill(self.pid() as libc::pid_t, sig) };
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

/// Polls `cond` every millisecond until it holds or `timeout` passes; returns whether it held.
pub fn wait_until(timeout: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + timeout;
    loop {
        if cond() {
            return true;
        }
        if Instant::now() >= end {
            return false;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
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
