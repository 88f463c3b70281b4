//! Real ALSA paced in real time without a sound card: a `jackd -d dummy` server with a
//! private name, and ALSA's `jack` PCM plugin (`bass_jack`) pointed at it.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::Instant;

use crate::{OwnedChild, TempDir};

/// A `jackd -d dummy` server (2 capture ports, 256-frame periods) with a private name,
/// sent SIGTERM on drop so that it releases its registry slot (SIGKILL if it lingers for 5 s).
pub struct Jackd {
    child: OwnedChild,
}

impl Jackd {
    /// Starts the server at `rate` Hz and waits (`jack_wait`, 10 s) until it answers; its
    /// log goes to `log_dir/jackd-<attempt>.log`. Servers starting at the same instant can
    /// trip over JACK's shared registry, so starts are serialised and retried three times.
    pub fn start(name: &str, rate: u32, log_dir: &Path) -> Jackd {
        Jackd::start_sched(name, rate, 256, false, log_dir)
    }

    /// [`Jackd::start`] with `period`-frame cycles and real-time scheduling (jackd's default,
    /// SCHED_FIFO) when `realtime`. The dummy backend restarts its timebase when a cycle wakes
    /// more than a period late (`JackTimedDriver`: "Process XRun"), and the frames' time line
    /// then steps by the lateness (measured here at load 5: 12.5 and 37 ms steps without
    /// real-time scheduling, 3 ms with it at 256 frames), which no clock model follows;
    /// real-time scheduling and a longer period make that rarer. jackd carries on without
    /// real-time scheduling where it is not permitted.
    pub fn start_sched(name: &str, rate: u32, period: u32, realtime: bool, log_dir: &Path) -> Jackd {
        static START: Mutex<()> = Mutex::new(());
        let _serial = START.lock().unwrap_or_else(|e| e.into_inner());
        let log_path = |attempt: u32| log_dir.join(format!("jackd-{attempt}.log"));
        for attempt in 1..=3 {
            let log = std::fs::File::create(log_path(attempt)).expect("create the jackd log");
            let child = Command::new("jackd")
                .args(["-n", name])
                .args(if realtime { &[][..] } else { &["--no-realtime"][..] })
                .args(["-d", "dummy", "-r", &rate.to_string()])
                .args(["-p", &period.to_string(), "-C", "2", "-P", "2"])
                .env("JACK_NO_AUDIO_RESERVATION", "1")
                .stdout(Stdio::null())
                .stderr(log)
                .spawn()
                .expect("start jackd (apt-get install jackd2; scripts/install-deps.sh)");
            let mut j = Jackd { child: OwnedChild(Some(child)) };
            let up = Command::new("jack_wait")
                .args(["-s", name, "-w", "-t", "10"])
                .env("JACK_NO_START_SERVER", "1")
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success());
            if up {
                return j;
            }
            j.kill(rustix::process::Signal::KILL.as_raw());
            eprintln!("jackd -n {name}: attempt {attempt} did not come up");
        }
        let logs: Vec<String> =
            (1..=3).map(|a| std::fs::read_to_string(log_path(a)).unwrap_or_default()).collect();
        panic!("jackd -n {name} did not come up; logs:\n{}", logs.join("\n---\n"));
    }

    /// Sends `sig` and reaps the server; returns the instant the signal was sent.
    pub fn kill(&mut self, sig: i32) -> Instant {
        let t = Instant::now();
        self.child.kill(sig);
        t
    }
}

/// Why the jack rig cannot run here (`jackd`, `jack_wait` or ALSA's jack plugin missing),
/// or `None` if it can.
pub fn jack_missing() -> Option<String> {
    for tool in ["jackd", "jack_wait"] {
        let found = Command::new("sh")
            .args(["-c", &format!("command -v {tool}")])
            .output()
            .is_ok_and(|o| o.status.success());
        if !found {
            return Some(format!("{tool} not installed"));
        }
    }
    let plugin =
        ["/usr/lib/x86_64-linux-gnu/alsa-lib", "/usr/lib/aarch64-linux-gnu/alsa-lib", "/usr/lib/alsa-lib"]
            .iter()
            .any(|d| Path::new(d).join("libasound_module_pcm_jack.so").exists());
    if !plugin {
        return Some("ALSA jack plugin (libasound2-plugins) not installed".into());
    }
    None
}

/// ALSA's `jack` plugin as PCM `bass_jack` (capturing `system:capture_1` and `_2`) for a
/// jackd of a given name: the ALSA configuration file lives in the rig's directory, and
/// [`JackRig::env`] is the environment a broker needs to use it.
pub struct JackRig {
    /// The rig's directory (ALSA configuration, jackd logs; usable as a runtime directory).
    pub dir: TempDir,
    /// The jackd server name. Keep it fixed per test: JACK has 8 server slots per machine
    /// and frees a SIGKILLed server's slot only when a server of the same name starts.
    pub jack_name: String,
    /// `$ALSA_CONFIG_PATH`: ALSA's own configuration, then the rig's.
    pub alsa_path: String,
}

impl JackRig {
    /// Writes the `bass_jack` PCM definition into `dir`.
    pub fn new(dir: TempDir, jack_name: &str) -> JackRig {
        JackRig::with_pcms(dir, jack_name, &[("bass_jack", ["system:capture_1", "system:capture_2"])])
    }

    /// Writes one ALSA `jack` capture PCM per `(name, [jack port of channel 0, of channel 1])`
    /// into `dir`: several PCMs may capture the same JACK ports (one clock, one signal).
    pub fn with_pcms(dir: TempDir, jack_name: &str, pcms: &[(&str, [&str; 2])]) -> JackRig {
        let rc: PathBuf = dir.join("asoundrc");
        let text: String = pcms
            .iter()
            .map(|(pcm, [a, b])| {
                format!("pcm.{pcm} {{\n  type jack\n  capture_ports {{ 0 \"{a}\" 1 \"{b}\" }}\n}}\n")
            })
            .collect();
        std::fs::write(&rc, text).expect("write the ALSA configuration");
        let alsa_path = format!("/usr/share/alsa/alsa.conf:{}", rc.display());
        JackRig { dir, jack_name: jack_name.to_owned(), alsa_path }
    }

    /// The rig's directory.
    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    /// Starts this rig's jackd at `rate` Hz (logs in the rig's directory).
    pub fn jackd(&self, rate: u32) -> Jackd {
        Jackd::start(&self.jack_name, rate, self.path())
    }

    /// [`JackRig::jackd`] with `period`-frame cycles and real-time scheduling (see
    /// [`Jackd::start_sched`]).
    pub fn jackd_rt(&self, rate: u32, period: u32) -> Jackd {
        Jackd::start_sched(&self.jack_name, rate, period, true, self.path())
    }

    /// The environment of a process that captures `bass_jack` from this rig's jackd.
    pub fn env(&self) -> [(&str, &str); 4] {
        [
            ("ALSA_CONFIG_PATH", &self.alsa_path),
            ("JACK_DEFAULT_SERVER", &self.jack_name),
            ("JACK_NO_START_SERVER", "1"),
            ("JACK_NO_AUDIO_RESERVATION", "1"),
        ]
    }
}

impl Drop for JackRig {
    /// Removes the POSIX semaphores libjack leaves in /dev/shm for clients of this rig's
    /// server (`jack_sem.<uid>_<server>_<client>...`) and the server's own request socket
    /// (`jack_<server>_<uid>_<n>`) when a client or the server was killed: a test deletes what
    /// it creates. The registry (`jack-shm-registry`) is shared by every server on the machine
    /// and stays.
    fn drop(&mut self) {
        let infix = format!("_{}_", self.jack_name);
        let socket = format!("jack_{}_", self.jack_name);
        let Ok(entries) = std::fs::read_dir("/dev/shm") else { return };
        for e in entries.flatten() {
            let name = e.file_name();
            let name = name.to_string_lossy();
            if (name.starts_with("jack_sem.") && name.contains(&infix)) || name.starts_with(&socket) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}
