//! The PipeWire side of part 7: the tools, the capture client compiled here, the daemon in a
//! private runtime directory and its N clients linked to the virtual source.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::e2e::Proc;
use crate::procs::Child;
use crate::workload::{QUANTUM, RATE};

/// Scheduling of both sides in one comparison.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Sched {
    /// SCHED_OTHER everywhere: PipeWire without its realtime module, bassd `--rt-priority 0`.
    #[default]
    Normal,
    /// SCHED_FIFO: the daemons' processing threads at [`RT_DAEMON`], the clients' at
    /// [`RT_CLIENT`] (PipeWire's module-rt in the daemon and in each client; bassd's capture
    /// thread; the bass readers set it themselves).
    Fifo,
}

/// SCHED_FIFO priority of the daemons' threads in the realtime comparison (bassd's default).
pub const RT_DAEMON: u32 = 70;
/// SCHED_FIFO priority of the clients' threads in the realtime comparison.
pub const RT_CLIENT: u32 = 60;

/// The daemon configuration (`@RT_MODULE@` is replaced by the realtime module or nothing).
pub(super) const CONF: &str = include_str!("../../pipewire/bench.conf");
/// The capture clients' configuration.
const CLIENT_CONF: &str = include_str!("../../pipewire/client.conf");
/// The capture client's source.
pub(super) const CLIENT_C: &str = include_str!("../../pipewire/pw-capture-client.c");

/// The PipeWire tools and the compiled client.
pub(super) struct Tools {
    client: PathBuf,
    pub(super) version: String,
}

/// Finds pipewire and pw-link, and compiles the capture client into `dir`.
pub(super) fn tools(dir: &Path) -> Result<Tools, String> {
    let version = Command::new("pipewire")
        .arg("--version")
        .output()
        .map_err(|e| format!("pipewire not found ({e}); scripts/install-deps.sh --with-bench installs it"))?;
    // "pipewire\nCompiled with libpipewire 0.3.65\nLinked with libpipewire 0.3.65": the last word.
    let version = String::from_utf8_lossy(&version.stdout)
        .lines()
        .find_map(|l| l.strip_prefix("Linked with libpipewire "))
        .map_or_else(|| "version unknown".to_owned(), |v| format!("PipeWire {}", v.trim()));
    Command::new("pw-link").arg("--version").output().map_err(|e| format!("pw-link not found: {e}"))?;
    let pc = |what: &str| {
        Command::new("pkg-config")
            .args([what, "libpipewire-0.3"])
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
            .ok_or_else(|| "libpipewire-0.3 not found by pkg-config (libpipewire-0.3-dev)".to_owned())
    };
    let (cflags, libs) = (pc("--cflags")?, pc("--libs")?);
    let src = dir.join("pw-capture-client.c");
    std::fs::write(&src, CLIENT_C).map_err(|e| e.to_string())?;
    let client = dir.join("pw-capture-client");
    // PipeWire's headers use GNU statement expressions: included as system headers, so that
    // -Wpedantic applies to our code only.
    let flags = cflags.split_whitespace().map(|f| match f.strip_prefix("-I") {
        Some(d) => format!("-isystem{d}"),
        None => f.to_owned(),
    });
    let out = Command::new(std::env::var("CC").unwrap_or_else(|_| "cc".into()))
        .args(["-std=c11", "-D_GNU_SOURCE", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror"])
        .args(flags)
        .arg("-o")
        .arg(&client)
        .arg(&src)
        .args(libs.split_whitespace())
        .output()
        .map_err(|e| format!("cc: {e}"))?;
    if !out.status.success() {
        return Err(format!("compiling pw-capture-client failed: {}", String::from_utf8_lossy(&out.stderr)));
    }
    Ok(Tools { client, version })
}

/// A PipeWire daemon in its own runtime directory.
pub(super) struct Daemon {
    pub(super) proc: Proc,
    dir: PathBuf,
}

impl Daemon {
    pub(super) fn start(dir: &Path, sched: Sched) -> Result<Daemon, String> {
        let _ = std::fs::remove_dir_all(dir);
        std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
        let conf = dir.join("bench.conf");
        std::fs::write(&conf, CONF.replace("@RT_MODULE@", &rt_module(sched, RT_DAEMON)))
            .map_err(|e| e.to_string())?;
        // The clients' configuration: Debian's client.conf, with the realtime module or not.
        std::fs::write(
            dir.join("client.conf"),
            CLIENT_CONF.replace("@RT_MODULE@", &rt_module(sched, RT_CLIENT)),
        )
        .map_err(|e| e.to_string())?;
        let log = std::fs::File::create(dir.join("pipewire.log")).map_err(|e| e.to_string())?;
        let mut cmd = Command::new("pipewire");
        cmd.arg("-c").arg(&conf).stdin(Stdio::null()).stdout(Stdio::null()).stderr(log);
        env(&mut cmd, dir);
        cmd.env("PIPEWIRE_CONFIG_NAME", &conf);
        let proc = Proc(cmd.spawn().map_err(|e| format!("start pipewire: {e}"))?);
        let t = Instant::now();
        while !dir.join("pipewire-0").exists() {
            if t.elapsed() > Duration::from_secs(5) {
                return Err(format!("pipewire did not open its socket in 5 s (log: {})", dir.display()));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(Daemon { proc, dir: dir.to_owned() })
    }
}

/// PipeWire's realtime module at `prio`, for [`Sched::Fifo`]; nothing otherwise.
pub(super) fn rt_module(sched: Sched, prio: u32) -> String {
    match sched {
        Sched::Normal => String::new(),
        Sched::Fifo => format!(
            "{{ name = libpipewire-module-rt args = {{ rt.prio = {prio} nice.level = -11 rt.time.soft = -1 rt.time.hard = -1 }} }}"
        ),
    }
}

/// The private runtime directory of a PipeWire process (with the clients' configuration in
/// it), and no session bus.
pub(super) fn env(cmd: &mut Command, dir: &Path) {
    cmd.env("XDG_RUNTIME_DIR", dir)
        .env("PIPEWIRE_RUNTIME_DIR", dir)
        .env("PIPEWIRE_CONFIG_NAME", dir.join("client.conf"))
        .env_remove("PIPEWIRE_REMOTE")
        .env_remove("DBUS_SESSION_BUS_ADDRESS");
}

/// Starts `n` capture clients and links each to the source node.
pub(super) fn pw_clients(t: &Tools, d: &Daemon, n: usize) -> Result<Vec<Child>, String> {
    let mut kids = Vec::new();
    for k in 0..n {
        let mut cmd = Command::new(&t.client);
        cmd.args([format!("bench-pw-{k}"), QUANTUM.to_string(), RATE.to_string()]);
        env(&mut cmd, &d.dir);
        kids.push(Child::spawn_command(cmd));
    }
    for (k, kid) in kids.iter_mut().enumerate() {
        kid.ready();
        for (out, inp) in [("capture_FL", "input_1"), ("capture_FR", "input_2")] {
            let mut cmd = Command::new("pw-link");
            cmd.arg(format!("bench-source:{out}")).arg(format!("bench-pw-{k}:{inp}"));
            env(&mut cmd, &d.dir);
            let o = cmd.output().map_err(|e| format!("pw-link: {e}"))?;
            if !o.status.success() {
                return Err(format!("pw-link bench-pw-{k}:{inp}: {}", String::from_utf8_lossy(&o.stderr)));
            }
        }
    }
    Ok(kids)
}
