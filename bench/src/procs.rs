//! Child processes (this binary re-executed in a `child` role) and scratch space.
//!
//! Children talk to the parent through their stdout: one line `ready` once set up, then
//! result lines when they finish. Ports live in a scratch directory on tmpfs, passed to
//! children as `BASS_RUNTIME_DIR`.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{ChildStdout, Command, Stdio};

/// A scratch directory under /dev/shm (tmpfs, like the ports of a real broker), removed on drop.
pub struct Scratch {
    /// The directory.
    pub dir: PathBuf,
}

impl Scratch {
    /// Creates `/dev/shm/bass-bench.PID` (or under $TMPDIR if /dev/shm is missing).
    pub fn new() -> Scratch {
        let base =
            if Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        let dir = base.join(format!("bass-bench.{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("create the scratch directory");
        std::env::set_var(bassport::paths::RUNTIME_DIR_ENV, &dir);
        Scratch { dir }
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// A running child process.
pub struct Child {
    proc: std::process::Child,
    out: BufReader<ChildStdout>,
}

impl Child {
    /// Starts `bass-bench child ROLE ARGS...`.
    ///
    /// Experiment hook: with `BASS_BENCH_READER_EXE` set, bass reader roles run from that
    /// executable instead (a bass-bench built against a modified libbassclient).
    pub fn spawn(role: &str, args: &[String]) -> Child {
        let alt = std::env::var_os("BASS_BENCH_READER_EXE")
            .filter(|v| !v.is_empty())
            .filter(|_| matches!(role, "wake-reader" | "ring-reader" | "cpu-reader" | "poll-reader"));
        let exe = alt
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| std::env::current_exe().expect("own executable"));
        Child::spawn_exe(&exe, role, args)
    }

    /// Starts `EXE child ROLE ARGS...`.
    pub fn spawn_exe(exe: &Path, role: &str, args: &[String]) -> Child {
        let mut cmd = Command::new(exe);
        cmd.arg("child").arg(role).args(args);
        Child::spawn_command(cmd)
    }

    /// Starts `cmd` (any program speaking the same protocol: `ready`, then result lines).
    pub fn spawn_command(mut cmd: Command) -> Child {
        let mut proc = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn a child process");
        let out = BufReader::new(proc.stdout.take().expect("child stdout"));
        Child { proc, out }
    }

    /// Process id.
    pub fn pid(&self) -> u32 {
        self.proc.id()
    }

    /// Reads one line (without the newline); panics if the child closed its stdout.
    pub fn line(&mut self) -> String {
        let mut s = String::new();
        let n = self.out.read_line(&mut s).expect("read from a child");
        assert!(n > 0, "child {} exited early", self.proc.id());
        s.trim_end().to_owned()
    }

    /// Waits for the child's `ready` line.
    pub fn ready(&mut self) {
        let l = self.line();
        assert_eq!(l, "ready", "child {} said {l:?}", self.proc.id());
    }

    /// Reads the remaining lines and reaps the child.
    pub fn finish(mut self) -> Vec<String> {
        let mut lines = Vec::new();
        let mut s = String::new();
        while self.out.read_line(&mut s).map(|n| n > 0).unwrap_or(false) {
            lines.push(s.trim_end().to_owned());
            s.clear();
        }
        let _ = self.proc.wait();
        lines
    }
}

/// Starts `n` children of one role and waits until each said `ready`.
pub fn spawn_ready(n: usize, role: &str, args: &[String]) -> Vec<Child> {
    let mut kids: Vec<Child> = (0..n).map(|_| Child::spawn(role, args)).collect();
    for k in &mut kids {
        k.ready();
    }
    kids
}

/// Tells the parent this child is set up.
pub fn say_ready() {
    let mut o = std::io::stdout().lock();
    let _ = writeln!(o, "ready");
    let _ = o.flush();
}

/// Parses `key=value` words of a result line into f64 values.
pub fn field(line: &str, key: &str) -> Option<f64> {
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(key).and_then(|r| r.strip_prefix('=')).and_then(|v| v.parse().ok()))
}

/// Lines of several finished children, concatenated.
pub fn finish_all(kids: Vec<Child>) -> Vec<String> {
    kids.into_iter().flat_map(Child::finish).collect()
}

/// Resident memory counters of a process from /proc/PID/status and smaps_rollup (KiB).
#[derive(Clone, Copy, Debug, Default)]
pub struct Rss {
    /// VmRSS.
    pub rss: u64,
    /// RssAnon (private heap and stack).
    pub anon: u64,
    /// RssFile (executable and libraries).
    pub file: u64,
    /// RssShmem (shared memory, e.g. the port mapping).
    pub shmem: u64,
    /// Pss (shared pages divided by the number of processes mapping them).
    pub pss: u64,
}

fn kib(text: &str, key: &str) -> u64 {
    text.lines()
        .find(|l| l.starts_with(key))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

/// Reads the memory counters of `pid` ("self" for this process).
pub fn rss_of(pid: &str) -> Rss {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let rollup = std::fs::read_to_string(format!("/proc/{pid}/smaps_rollup")).unwrap_or_default();
    Rss {
        rss: kib(&status, "VmRSS:"),
        anon: kib(&status, "RssAnon:"),
        file: kib(&status, "RssFile:"),
        shmem: kib(&status, "RssShmem:"),
        pss: kib(&rollup, "Pss:"),
    }
}

impl Rss {
    /// As `key=value` words.
    pub fn words(&self) -> String {
        format!(
            "rss={} anon={} file={} shmem={} pss={}",
            self.rss, self.anon, self.file, self.shmem, self.pss
        )
    }

    /// From `key=value` words.
    pub fn parse(line: &str) -> Rss {
        let g = |k| field(line, k).unwrap_or(0.0) as u64;
        Rss { rss: g("rss"), anon: g("anon"), file: g("file"), shmem: g("shmem"), pss: g("pss") }
    }
}

/// CPU time (user + system) of this process so far, in ns.
pub fn process_cpu_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid out-pointer; the clock always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}
