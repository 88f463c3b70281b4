//! The running daemon's name: the instance lock and the files under the runtime directory.

use std::path::PathBuf;

use anyhow::bail;
use bassclient::format::State;
use bassclient::instance::{Instance, InstanceError};
use bassclient::reader::Port;

use crate::config::Config;

/// The running daemon's name: the instance lock (`bassclient::instance`, the same as
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
            // that died (or, under systemd, left for this one to take back from the fd store).
            let live = matches!(i.state, Some(State::Idle | State::Starting | State::Capturing));
            if live && !i.writer_alive {
                tracing::warn!(
                    "port {} was left capturing by a broker that is gone (pid {}); unless this broker \
                     takes it back from systemd's fd store, its readers see the writer gone and the \
                     next Acquire replaces it",
                    port.display(),
                    i.writer_pid
                );
            }
        }
    }
    let socket_name = inst.socket_name();
    Ok(Files { inst, socket, socket_name })
}
