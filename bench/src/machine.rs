//! What machine the numbers come from: CPU, cores, kernel, load.

use std::process::Command;

/// A description of the machine and its state when the run started.
#[derive(Clone, Debug, Default)]
pub struct Machine {
    /// CPU model name from /proc/cpuinfo.
    pub cpu: String,
    /// Online CPUs.
    pub cores: usize,
    /// Kernel release.
    pub kernel: String,
    /// Memory in GiB.
    pub mem_gib: f64,
    /// Load average (1, 5, 15 min) at the start.
    pub load_start: String,
    /// rustc version used for the build (if rustc is on PATH).
    pub rustc: String,
    /// The CPU vendor (`GenuineIntel`, `AuthenticAMD`, ...).
    pub vendor: String,
    /// The copy-related CPU flags present (erms, fsrm, avx2, avx512f).
    pub copy_flags: Vec<&'static str>,
    /// The reader's copy path on this CPU (`bassport::ring::copy_path`).
    pub copy_path: &'static str,
    /// Hypervisor flag present in /proc/cpuinfo.
    pub virtualized: bool,
    /// UTC time of the run.
    pub date: String,
}

fn cmd(prog: &str, args: &[&str]) -> String {
    Command::new(prog)
        .args(args)
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
        .unwrap_or_default()
}

/// Current load average as text.
pub fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default()
}

impl Machine {
    /// Looks at /proc and a few commands.
    pub fn describe() -> Machine {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let cpu = cpuinfo
            .lines()
            .find(|l| l.starts_with("model name"))
            .and_then(|l| l.split(':').nth(1))
            .map(|s| s.trim().to_owned())
            .unwrap_or_else(|| "unknown".into());
        let field = |name: &str| {
            cpuinfo
                .lines()
                .find(|l| l.starts_with(name))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_owned())
                .unwrap_or_default()
        };
        let flags = field("flags");
        let flags: Vec<&str> = flags.split_whitespace().collect();
        let virtualized = flags.contains(&"hypervisor");
        let copy_flags =
            ["erms", "fsrm", "avx2", "avx512f"].into_iter().filter(|f| flags.contains(f)).collect();
        let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
        let mem_kib: f64 = meminfo
            .lines()
            .find(|l| l.starts_with("MemTotal:"))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.0);
        Machine {
            cpu,
            vendor: field("vendor_id"),
            copy_flags,
            copy_path: bassport::ring::copy_path().name(),
            cores: std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
            kernel: cmd("uname", &["-r"]),
            mem_gib: mem_kib / 1024.0 / 1024.0,
            load_start: loadavg(),
            rustc: cmd("rustc", &["--version"]),
            virtualized,
            date: cmd("date", &["-u", "+%Y-%m-%d %H:%M UTC"]),
        }
    }

    /// One line for the console.
    pub fn one_line(&self) -> String {
        format!(
            "{} ({}, {}; copy path {}) ({} cores{}), Linux {}, {:.0} GiB, load {}",
            self.cpu,
            self.vendor,
            self.copy_flags.join(" "),
            self.copy_path,
            self.cores,
            if self.virtualized { ", virtual machine" } else { "" },
            self.kernel,
            self.mem_gib,
            self.load_start
        )
    }
}
