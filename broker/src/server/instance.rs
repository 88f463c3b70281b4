//! The running daemon's name: the instance lock and the files under the runtime directory.

use std::path::{Path, PathBuf};

use anyhow::bail;
use basskit::instance::{Instance, InstanceError};
use bassport::format::State;
use bassport::reader::Port;

use crate::config::Config;
use crate::supervise::PORT_FD_NAME;

/// The running daemon's name: the instance lock (`basskit::instance`, the same as
/// `bass-bridge mirror` takes), its socket removed at exit.
pub(super) struct Files {
    pub(super) inst: Instance,
    pub(super) socket: PathBuf,
    pub(super) socket_name: String,
}

impl Drop for Files {
    fn drop(&mut self) {
        self.inst.remove_socket();
    }
}

/// Takes the instance lock and clears what a dead broker of ours left.
///
/// Every file here is opened relative to the runtime directory's fd without following
/// symlinks, created with O_EXCL where new, and refused if it belongs to another user
/// (docs/reliability.md, threat model). The system runtime directory (`/run/bass`, root) is
/// created 0755 if absent and must be ours and not writable by others.
pub(super) fn take_instance(cfg: &Config) -> anyhow::Result<Files> {
    let inst = match Instance::take(&cfg.name) {
        Ok(i) => i,
        Err(InstanceError::Held { holder, socket, .. }) => bail!(
            "a broker named {:?} is already running ({holder}, control socket {}); \
             stop it first or start this one with --name OTHER",
            cfg.name,
            socket.display()
        ),
        Err(InstanceError::SystemName { found, .. }) => bail!(
            "a system broker named {:?} serves {}; clients would find it before this one: \
             start this broker with --name OTHER",
            cfg.name,
            found.display()
        ),
        Err(e) => return Err(e.into()),
    };
    let socket = inst.socket_path();
    if inst.removed_stale_socket {
        tracing::warn!("removed the stale control socket {} left by a previous broker", socket.display());
    }
    let port = inst.port_path();
    if let Ok(p) = Port::open_path(&port) {
        if let Ok(i) = p.info() {
            // A port its broker stopped is no news; one still "capturing" was left by a broker
            // that died, or, under a service manager, left for this one to take back.
            let live = matches!(i.state, Some(State::Idle | State::Starting | State::Capturing));
            if live && !i.writer_alive {
                match left_capturing(&port, i.writer_pid, port_handed_back()) {
                    (Left::ForThisBroker, msg) => tracing::info!("{msg}"),
                    (Left::Abandoned, msg) => tracing::warn!("{msg}"),
                }
            }
        }
    }
    let socket_name = inst.socket_name();
    Ok(Files { inst, socket, socket_name })
}

/// What a port left capturing by a broker that is gone means to its successor.
#[derive(Debug, PartialEq, Eq)]
enum Left {
    /// The service manager hands the port back (its fd store): the predecessor left it for
    /// this broker. A `systemctl restart` and a crash under systemd look the same here (the
    /// port and the store hold the same things after both); the manager's journal says which
    /// ("Main process exited, code=killed"), so the routine restart is no warning.
    ForThisBroker,
    /// Nothing hands it back: its broker died and its readers see the writer gone.
    Abandoned,
}

/// How the successor reports port `port`, left capturing by pid `pid`.
fn left_capturing(port: &Path, pid: u32, handed_back: bool) -> (Left, String) {
    if handed_back {
        let msg = format!(
            "port {} was left capturing by the previous broker (pid {pid}) for this one, which \
             takes it back from the service manager's fd store",
            port.display()
        );
        (Left::ForThisBroker, msg)
    } else {
        let msg = format!(
            "port {} was left capturing by a broker that is gone (pid {pid}), and no service \
             manager hands it back: its readers see the writer gone and the next Acquire replaces it",
            port.display()
        );
        (Left::Abandoned, msg)
    }
}

/// Whether the service manager passes this process a port (`LISTEN_PID` ours, `LISTEN_FDNAMES`
/// naming [`PORT_FD_NAME`]); read before `Supervisor::take_handed` takes the descriptors.
fn port_handed_back() -> bool {
    let var = |k| std::env::var(k).ok();
    handed_back(var("LISTEN_PID").as_deref(), var("LISTEN_FDNAMES").as_deref(), std::process::id())
}

fn handed_back(listen_pid: Option<&str>, names: Option<&str>, own_pid: u32) -> bool {
    listen_pid.and_then(|p| p.trim().parse::<u32>().ok()) == Some(own_pid)
        && names.is_some_and(|n| n.split(':').any(|name| name == PORT_FD_NAME))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_port_the_service_manager_hands_back_is_no_warning_one_nobody_takes_back_is() {
        // Before issue 33: every `systemctl restart` logged the WARN "left capturing by a
        // broker that is gone ... unless this broker takes it back".
        let port = Path::new("/run/bass/bass-default.port");
        let (kind, msg) = left_capturing(port, 41, true);
        assert_eq!(kind, Left::ForThisBroker);
        assert!(msg.contains("previous broker (pid 41)") && !msg.contains("gone"), "{msg}");
        let (kind, msg) = left_capturing(port, 41, false);
        assert_eq!(kind, Left::Abandoned);
        assert!(msg.contains("gone (pid 41)") && msg.contains("writer gone"), "{msg}");
    }

    #[test]
    fn only_a_port_passed_to_this_process_counts_as_handed_back() {
        let names = Some("bass-port:bass-acquisition");
        assert!(handed_back(Some("7"), names, 7));
        assert!(!handed_back(Some("8"), names, 7), "another process's descriptors");
        assert!(!handed_back(None, names, 7));
        assert!(!handed_back(Some("7"), Some("bass-acquisition"), 7), "no port among them");
        assert!(!handed_back(Some("7"), None, 7));
        assert!(!handed_back(Some("7"), Some("bass-portx"), 7));
    }
}
