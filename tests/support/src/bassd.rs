//! A real `bassd` per test: its own runtime directory (so tests run in parallel without
//! touching the process environment), started, waited for, and stopped on drop.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use bassport::control::Client;
use bassport::Port;

use crate::{bassd_bin, send_signal, OwnedChild, PATIENCE};

/// A running `bassd`, sent SIGTERM on drop (bassd removes its socket and port; SIGKILL if
/// it lingers for 5 s).
pub struct Bassd {
    child: OwnedChild,
    /// Its runtime directory (`$BASS_RUNTIME_DIR`).
    pub dir: PathBuf,
    /// The broker name (`--name`).
    pub name: String,
    log: tempfile::NamedTempFile,
}

/// How to start a `bassd`: [`Bassd::builder`], then [`BassdBuilder::start`].
pub struct BassdBuilder {
    dir: PathBuf,
    name: String,
    args: Vec<OsString>,
    env: Vec<(OsString, OsString)>,
    stall_ms: Option<u64>,
    log_level: String,
    handed: Vec<(String, std::os::fd::OwnedFd)>,
    wrapper: Vec<OsString>,
}

impl BassdBuilder {
    /// Runs bassd under a wrapper command, e.g. `["unshare", "--pid", "--fork"]`: the
    /// process the test holds (and signals) is then the wrapper's.
    pub fn wrapper(mut self, cmd: &[&str]) -> BassdBuilder {
        self.wrapper = cmd.iter().map(OsString::from).collect();
        self
    }

    /// Extra command-line arguments (after the rig's own; a repeated option wins).
    pub fn args(mut self, args: &[&str]) -> BassdBuilder {
        self.args.extend(args.iter().map(OsString::from));
        self
    }

    /// Extra environment variables.
    pub fn envs(mut self, env: &[(&str, &str)]) -> BassdBuilder {
        self.env.extend(env.iter().map(|(k, v)| (OsString::from(k), OsString::from(v))));
        self
    }

    /// `--stall-ms MS`, or `None` for bassd's own threshold.
    pub fn stall_ms(mut self, ms: Option<u64>) -> BassdBuilder {
        self.stall_ms = ms;
        self
    }

    /// Descriptors the service manager hands back on start (`LISTEN_FDS`, `LISTEN_FDNAMES`,
    /// `LISTEN_PID`: see [`crate::FakeManager`]), at 3, 4, ... in this order.
    pub fn handed_fds(mut self, fds: Vec<(String, std::os::fd::OwnedFd)>) -> BassdBuilder {
        self.handed = fds;
        self
    }

    /// `$BASS_LOG` of the broker (its log is kept in a temporary file, see [`Bassd::log_text`]).
    pub fn log_level(mut self, level: &str) -> BassdBuilder {
        level.clone_into(&mut self.log_level);
        self
    }

    /// Starts `bassd --name NAME --rt-priority 0 [--stall-ms MS] ARGS` and waits until its
    /// control socket answers a status request. No real-time priority: the unpaced ALSA
    /// `file` plugin would spin a core at SCHED_FIFO.
    pub fn start(self) -> Bassd {
        let log = tempfile::Builder::new()
            .prefix(&format!("bassd-{}-", self.name))
            .suffix(".log")
            .tempfile()
            .expect("create the broker's log file");
        let supervised = !self.handed.is_empty() || self.env.iter().any(|(k, _)| k == "WATCHDOG_USEC");
        let mut cmd = if supervised {
            // LISTEN_PID and WATCHDOG_PID must be bassd's pid, as a service manager sets
            // them: the shell's, which exec keeps.
            let mut c = Command::new("/bin/sh");
            let script = "[ -n \"$WATCHDOG_USEC\" ] && export WATCHDOG_PID=$$; \
                          [ -n \"$LISTEN_FDS\" ] && export LISTEN_PID=$$; exec \"$0\" \"$@\"";
            c.args(["-c", script, &bassd_bin()]);
            if !self.handed.is_empty() {
                let names: Vec<&str> = self.handed.iter().map(|(n, _)| n.as_str()).collect();
                c.env("LISTEN_FDS", names.len().to_string()).env("LISTEN_FDNAMES", names.join(":"));
                pass_fds(&mut c, &self.handed);
            }
            c
        } else if let Some((first, rest)) = self.wrapper.split_first() {
            let mut c = Command::new(first);
            c.args(rest).arg(bassd_bin());
            c
        } else {
            Command::new(bassd_bin())
        };
        cmd.arg("--name").arg(&self.name).args(["--rt-priority", "0"]);
        if let Some(ms) = self.stall_ms {
            cmd.arg("--stall-ms").arg(ms.to_string());
        }
        cmd.args(&self.args);
        cmd.env("BASS_RUNTIME_DIR", &self.dir).env("BASS_LOG", &self.log_level);
        cmd.envs(self.env.iter().map(|(k, v)| (k, v)));
        let stderr = log.reopen().expect("open the broker's log file");
        cmd.stdin(Stdio::null()).stdout(Stdio::null()).stderr(stderr);
        let child = cmd.spawn().expect("spawn bassd");
        let mut b = Bassd { child: OwnedChild(Some(child)), dir: self.dir, name: self.name, log };
        let deadline = Instant::now() + PATIENCE;
        loop {
            if b.try_client().and_then(|mut c| c.status()).is_ok() {
                return b;
            }
            if let Some(st) = b.child.get_mut().and_then(|c| c.try_wait().ok().flatten()) {
                panic!("bassd exited during start-up ({st}); log:\n{}", b.log_text());
            }
            assert!(
                Instant::now() < deadline,
                "bassd did not answer within {PATIENCE:?}; log:\n{}",
                b.log_text()
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Bassd {
    /// A broker named `name` in runtime directory `dir`, by default with the rig's
    /// `--stall-ms 1500` (see [`Bassd::start`]) and `BASS_LOG=info`.
    pub fn builder(dir: &Path, name: &str) -> BassdBuilder {
        BassdBuilder {
            dir: dir.to_owned(),
            name: name.to_owned(),
            args: Vec::new(),
            env: Vec::new(),
            stall_ms: Some(1500),
            log_level: "info".into(),
            handed: Vec::new(),
            wrapper: Vec::new(),
        }
    }

    /// The functional tests' broker: `bassd --name NAME --rt-priority 0 --stall-ms 1500 ARGS`
    /// with extra environment, logging at `info`. The stall threshold is one a loaded test
    /// machine cannot trip by accident.
    pub fn start(dir: &Path, name: &str, args: &[&str], env: &[(&str, &str)]) -> Bassd {
        Bassd::builder(dir, name).args(args).envs(env).start()
    }

    /// The fault suite's broker: bassd's own stall threshold (the one that runs in the field,
    /// which the device-loss tests measure) and only errors logged.
    pub fn start_stock(dir: &Path, name: &str, args: &[&str], env: &[(&str, &str)]) -> Bassd {
        Bassd::builder(dir, name).stall_ms(None).log_level("error").args(args).envs(env).start()
    }

    /// Starts a broker allowed to replay WAV files from `dir` (see [`crate::replay_args`]).
    pub fn start_replaying(dir: &Path, name: &str) -> Bassd {
        let extra = crate::replay_args(dir);
        let args: Vec<&str> = extra.iter().map(String::as_str).collect();
        Bassd::start(dir, name, &args, &[])
    }

    /// Process id (0 once reaped).
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Whether the process is still running (has not exited).
    pub fn is_running(&mut self) -> bool {
        self.child.get_mut().is_some_and(|c| matches!(c.try_wait(), Ok(None)))
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
    pub fn try_client(&self) -> bassport::Result<Client> {
        Client::connect_path(&self.socket(), &self.name)
    }

    /// A control client (panics if the broker does not answer).
    pub fn client(&self) -> Client {
        self.try_client().expect("connect to bassd")
    }

    /// The broker's port, opened for reading (panics if it cannot be).
    pub fn port(&self) -> Port {
        Port::open_path(&self.port_path()).expect("open the port")
    }

    /// The port of an acquisition still starting (`--acquire`: the control socket answers
    /// before the device is open and the port is linked), opened once it appears.
    pub fn port_once_acquired(&self) -> Port {
        let deadline = Instant::now() + PATIENCE;
        loop {
            match Port::open_path(&self.port_path()) {
                Ok(p) => return p,
                Err(e) => assert!(
                    Instant::now() < deadline,
                    "no port within {PATIENCE:?}: {e}; log:\n{}",
                    self.log_text()
                ),
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// What the broker has logged so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(self.log.path()).unwrap_or_default()
    }

    /// Sends `sig` (e.g. `libc::SIGTERM`); see [`Bassd::wait_exit`].
    pub fn signal(&self, sig: i32) {
        if self.child.id() != 0 {
            send_signal(self.child.id(), sig);
        }
    }

    /// Waits for the process to exit (after a signal), within [`PATIENCE`].
    pub fn wait_exit(&mut self) -> ExitStatus {
        let deadline = Instant::now() + PATIENCE;
        let child = self.child.get_mut().expect("bassd already reaped");
        loop {
            if let Some(st) = child.try_wait().expect("wait for bassd") {
                self.child.reaped();
                return st;
            }
            assert!(Instant::now() < deadline, "bassd did not exit within {PATIENCE:?}");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// Sends `sig` and reaps the process (for signals that end it, e.g. SIGKILL).
    pub fn kill(&mut self, sig: i32) {
        self.child.kill(sig);
    }
}

/// Makes the child find `fds` at descriptors 3, 4, ... (as the service manager passes them).
fn pass_fds(cmd: &mut Command, fds: &[(String, std::os::fd::OwnedFd)]) {
    use std::os::fd::AsRawFd;
    use std::os::unix::process::CommandExt;
    // Copies above any target number first, so no dup2 overwrites a source it still needs.
    let high: Vec<std::os::fd::OwnedFd> = fds
        .iter()
        .map(|(_, fd)| rustix::io::fcntl_dupfd_cloexec(fd, 100).expect("dup a handed descriptor"))
        .collect();
    let raws: Vec<i32> = high.iter().map(AsRawFd::as_raw_fd).collect();
    // SAFETY: the closure runs in the forked child before exec and only calls dup2, which
    // is async-signal-safe; `raws` are open descriptors (kept open by `high`, moved into the
    // closure, until the command is dropped).
    unsafe {
        cmd.pre_exec(move || {
            let _keep = &high;
            for (i, &fd) in raws.iter().enumerate() {
                if libc::dup2(fd, 3 + i as i32) < 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
}
