//! Test rig shared by the broker's integration tests: a private runtime directory per test,
//! a real `bassd` process, clients bound to that directory (no process-global environment
//! is touched, so the tests run in parallel), and small helpers.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use bassclient::control::{AcquireRequest, Client};
use bassclient::{Error, Port};

/// Generous bound for anything that should happen "soon" (never a pass/fail on timing:
/// only a guard against hanging forever).
pub const PATIENCE: Duration = Duration::from_secs(20);

static SEQ: AtomicU32 = AtomicU32::new(0);

/// A temporary directory removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        let n = SEQ.fetch_add(1, Ordering::Relaxed);
        let p = std::env::temp_dir().join(format!("bass-test-{tag}-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).expect("create temp dir");
        TempDir(p)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A running `bassd`.
pub struct Bassd {
    pub child: Option<Child>,
    pub dir: PathBuf,
    pub name: String,
    pub log: PathBuf,
}

pub fn bassd_bin() -> &'static str {
    env!("CARGO_BIN_EXE_bassd")
}

/// The `bass` under test: `$BASS_CLI` if set (to run a suite against another build, e.g. to
/// show that a test fails on the old code), else the one cargo built.
pub fn bass_bin() -> String {
    std::env::var("BASS_CLI").unwrap_or_else(|_| env!("CARGO_BIN_EXE_bass").to_owned())
}

impl Bassd {
    /// Starts `bassd --name NAME ARGS` in `dir` with extra environment, and waits until its
    /// control socket answers.
    pub fn start(dir: &Path, name: &str, args: &[&str], env: &[(&str, &str)]) -> Bassd {
        let log = dir.join(format!("bassd-{name}-{}.log", SEQ.fetch_add(1, Ordering::Relaxed)));
        let mut cmd = Command::new(bassd_bin());
        // No real-time priority (the unpaced ALSA file plugin would spin a core at SCHED_FIFO)
        // and a stall threshold that a loaded test machine cannot trip by accident.
        cmd.arg("--name").arg(name).arg("--rt-priority").arg("0").arg("--stall-ms").arg("1500").args(args);
        cmd.env("BASS_RUNTIME_DIR", dir).env("BASS_LOG", "info");
        for (k, v) in env {
            cmd.env(k, v);
        }
        cmd.stdout(Stdio::null()).stderr(std::fs::File::create(&log).expect("log file"));
        let child = cmd.spawn().expect("spawn bassd");
        let mut b = Bassd { child: Some(child), dir: dir.to_owned(), name: name.to_owned(), log };
        let deadline = Instant::now() + PATIENCE;
        loop {
            if let Ok(mut c) = b.try_client() {
                if c.status().is_ok() {
                    return b;
                }
            }
            if let Some(st) = b.child.as_mut().unwrap().try_wait().unwrap() {
                panic!("bassd exited early ({st}); log:\n{}", b.log_text());
            }
            assert!(Instant::now() < deadline, "bassd did not come up; log:\n{}", b.log_text());
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    pub fn socket(&self) -> PathBuf {
        self.dir.join(format!("bass-{}.sock", self.name))
    }

    pub fn port_path(&self) -> PathBuf {
        self.dir.join(format!("bass-{}.port", self.name))
    }

    pub fn try_client(&self) -> Result<Client, Error> {
        Client::connect_path(&self.socket(), &self.name)
    }

    pub fn client(&self) -> Client {
        self.try_client().expect("connect to bassd")
    }

    pub fn port(&self) -> Port {
        Port::open_path(&self.port_path()).expect("open the port")
    }

    pub fn pid(&self) -> i32 {
        self.child.as_ref().unwrap().id() as i32
    }

    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    pub fn signal(&self, sig: i32) {
        // SAFETY: kill(2) on our own child's pid.
        unsafe { libc::kill(self.pid(), sig) };
    }

    /// Waits for the process to exit (after a signal).
    pub fn wait_exit(&mut self) -> ExitStatus {
        let deadline = Instant::now() + PATIENCE;
        let child = self.child.as_mut().unwrap();
        loop {
            if let Some(st) = child.try_wait().unwrap() {
                self.child = None;
                return st;
            }
            assert!(Instant::now() < deadline, "bassd did not exit");
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for Bassd {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            // SAFETY: kill(2) on our own child's pid.
            unsafe { libc::kill(c.id() as i32, libc::SIGTERM) };
            let deadline = Instant::now() + Duration::from_secs(5);
            while c.try_wait().ok().flatten().is_none() {
                if Instant::now() > deadline {
                    let _ = c.kill();
                    let _ = c.wait();
                    break;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }
}

/// Extra `bassd` arguments that let clients replay WAV files from `dir` (`sim:file:`).
/// The broker's device policy refuses file replay by default; every replay test gets the
/// operator's widening from this one place.
pub fn replay_args(dir: &Path) -> Vec<String> {
    let d = dir.display();
    vec![
        "--allow-device".into(),
        format!("sim:file:{d}/*"),
        "--allow-device".into(),
        format!("sim:file-loop:{d}/*"),
    ]
}

impl Bassd {
    /// Starts a broker allowed to replay WAV files from `dir` (see [`replay_args`]).
    pub fn start_replaying(dir: &Path, name: &str) -> Bassd {
        let extra = replay_args(dir);
        let args: Vec<&str> = extra.iter().map(String::as_str).collect();
        Bassd::start(dir, name, &args, &[])
    }
}

pub fn req(device: &str, rate: u32, nfpc: u32, ncop: u32, channels: u32) -> AcquireRequest {
    AcquireRequest {
        device: device.into(),
        sample_rate: rate,
        frames_per_chunk: nfpc,
        chunks_on_port: ncop,
        channels,
        format: None,
    }
}

/// Reads frames `first..=last` of every channel (the frames must still be on the port).
pub fn read_frames(port: &Port, first: u64, last: u64) -> Vec<Vec<i32>> {
    let ch = port.geometry().channels as usize;
    let n = (last + 1 - first) as usize;
    let mut bufs = vec![vec![0i32; n]; ch];
    let mut nfr = first;
    let mut got = 0;
    while got < n {
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| &mut b[got..]).collect();
        let r = port.get_audio_data(n - got, &mut nfr, &mut outs).expect("getAudioData");
        assert_eq!(r.loss, 0, "frames {first}..={last} left the window before they were read");
        assert!(r.frames > 0, "frames {first}..={last} are not published");
        got += r.frames;
    }
    bufs
}

/// Waits for frame `frame` on `port` (panics on anything but success).
pub fn wait_frame(port: &Port, frame: u64) -> u64 {
    port.wait(frame, PATIENCE).unwrap_or_else(|e| panic!("waiting for frame {frame}: {e}"))
}

/// Polls `f` until it returns Some, within [`PATIENCE`].
pub fn eventually<T>(what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + PATIENCE;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "gave up waiting for {what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

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
