//! The one test rig of bass's Rust suites (the client library's tests in `libbassclient/tests`
//! through [`client`], the broker's integration tests in `broker/tests`, the fault suite in
//! `tests/faults`, the CLI's and the bridge's): private temporary directories, a real `bassd`
//! per test with its own runtime directory, a `jackd -d dummy` server behind ALSA's `jack`
//! plugin, the `bass` command line bound to a broker, bounded waits, and the rule for tests
//! that need root, `setpriv` or jackd ([`skip`]: in CI, with `BASS_TESTS_NO_SKIP=1`, a skip
//! is a failure).
//!
//! Nothing here mocks the thing under test: every helper starts real processes and uses real
//! shared memory. Every wait is bounded (a guard against a hanging test, never a pass/fail on
//! timing).
#![deny(unsafe_code)]

#[allow(unsafe_code)] // pre_exec: descriptors handed to a child bassd as a service manager would
mod bassd;
mod bins;
mod cli;
pub mod client;
#[allow(unsafe_code)] // libjack through dlopen: the tone player's JACK client
mod jack_tones;
mod jackd;
mod port;
mod skip;
mod systemd;
mod tempdir;
mod tmpfs;
mod wait;

pub use bassd::{Bassd, BassdBuilder};
pub use bins::{bass_bin, bassd_bin, bin_path};
pub use cli::{bass, bass_cmd, text};
pub use jack_tones::{tone_sample, JackTones, TONES, TONES_RATE};
pub use jackd::{jack_missing, JackRig, Jackd};
pub use port::{acquire_req, read_frames, replay_args, wait_frame};
pub use skip::{
    as_nobody, impersonation_missing, is_root, nobody_in_group, root_missing, setpriv, skip, skips_forbidden,
    NOBODY, NO_SKIP_VAR,
};
pub use systemd::{FakeManager, Notice};
pub use tempdir::{list_dir, TempDir};
pub use tmpfs::Tmpfs;
pub use wait::{eventually, wait_until, PATIENCE};

/// Sends signal `sig` (a `libc::SIG*` number) to process `pid`; errors (the process is
/// already gone) are ignored, as a test killing its own child expects.
pub fn send_signal(pid: u32, sig: i32) {
    let pid = i32::try_from(pid).ok().and_then(rustix::process::Pid::from_raw);
    let sig = rustix::process::Signal::from_named_raw(sig);
    if let (Some(pid), Some(sig)) = (pid, sig) {
        let _ = rustix::process::kill_process(pid, sig);
    }
}

/// A child process of the rig: sent a chosen signal and reaped on request; on drop ended
/// politely and reaped: SIGTERM (a broker removes its socket and port, a jackd releases its
/// registry slot), SIGKILL if it is still there after 5 s.
struct OwnedChild(Option<std::process::Child>);

impl OwnedChild {
    /// The process, unless it has been reaped.
    fn get_mut(&mut self) -> Option<&mut std::process::Child> {
        self.0.as_mut()
    }

    /// Process id (0 once reaped).
    fn id(&self) -> u32 {
        self.0.as_ref().map_or(0, std::process::Child::id)
    }

    /// Marks the process as reaped (after a successful wait).
    fn reaped(&mut self) {
        self.0 = None;
    }

    /// Sends `sig` and reaps the process (for signals that end it).
    fn kill(&mut self, sig: i32) {
        if let Some(mut c) = self.0.take() {
            send_signal(c.id(), sig);
            let _ = c.wait();
        }
    }
}

impl Drop for OwnedChild {
    fn drop(&mut self) {
        let Some(mut child) = self.0.take() else { return };
        send_signal(child.id(), rustix::process::Signal::TERM.as_raw());
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
        while child.try_wait().ok().flatten().is_none() {
            if std::time::Instant::now() > deadline {
                let _ = child.kill();
                let _ = child.wait();
                return;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
    }
}
