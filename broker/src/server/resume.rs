//! A broker restarted by its service manager takes back the port its predecessor left in the
//! fd store ([`crate::supervise`]) and goes on with the same acquisition: same port, same
//! epoch, `lastFrameIndex` continuing, the frames missed while no broker ran published as GAP.
//! A successor started with another command line, or for a replayed recording (whose frame
//! indices are the recording's), starts a new acquisition instead, and the old port is
//! marked superseded so that its readers are told (`Restarted`).

use bassport::control::{AcquireRequest, Status};
use bassport::format::{error_code, State};
use bassport::sys::monotonic_ns;
use std::fs::File;
use std::os::fd::AsRawFd;
use std::os::unix::fs::MetadataExt;
use std::path::Path;

use bassport::{memfd, paths, Backing, Writer};

use super::opening::{NextPort, Opening};
use super::Broker;
use crate::request::{self, DeviceKind};
use crate::supervise::{self, Handed, Stored};

/// The largest last frame index a port taken back may have: 2^53 (370 years at 768 kHz; a
/// frame index a double still holds exactly, as for replays). A forged port near the format's
/// limit would be taken back only to fail at its next publishes.
const MAX_RESUMED_FRAME: u64 = 1 << 53;

/// Whether `port`, handed back by the service manager, is this broker's own port: with file
/// backing the very file at the broker's port path `path` (not a copy, not another broker's
/// port); with memfd backing a size-sealed memfd made for a port of this broker's name.
/// What the service manager hands back is trusted no further than that.
fn own_port(port: &File, backing: Backing, name: &str, path: &Path) -> Result<(), String> {
    let sealed = memfd::size_sealed(std::os::fd::AsFd::as_fd(port));
    match backing {
        Backing::File => {
            if sealed {
                return Err("a sealed memfd, but this broker's ports are files".into());
            }
            let mine = path.symlink_metadata().map_err(|e| format!("{}: {e}", path.display()))?;
            let handed = port.metadata().map_err(|e| format!("fstat: {e}"))?;
            if (mine.dev(), mine.ino()) != (handed.dev(), handed.ino()) {
                return Err(format!("it is not the port file {}", path.display()));
            }
        }
        Backing::Memfd => {
            if !sealed {
                return Err("an unsealed file, but this broker's ports are sealed memfds".into());
            }
            let link = std::fs::read_link(format!("/proc/self/fd/{}", port.as_raw_fd()))
                .map_err(|e| format!("the descriptor's name: {e}"))?;
            let want = format!("/memfd:{} (deleted)", memfd::label(name));
            if link.as_os_str() != want.as_str() {
                return Err(format!("a memfd named {:?}, not {want:?}", link.display().to_string()));
            }
        }
    }
    Ok(())
}

impl Broker {
    /// Takes back a port from the fd store and starts its device again (the open runs like
    /// an Acquire's, [`Broker::poll_open`] finishes it). False when the port is not resumed
    /// (another command line, a replay, a port that does not validate): the caller starts
    /// afresh.
    pub(super) fn take_back(&mut self, handed: Handed) -> bool {
        let Handed { port, stored } = handed;
        let path = match paths::port_path(&self.cfg.name) {
            Ok(p) => p,
            Err(e) => {
                tracing::error!("cannot name the port to resume: {e}");
                return false;
            }
        };
        if let Err(why) = own_port(&port, self.cfg.port_backing, &self.cfg.name, &path) {
            tracing::warn!("the port in the fd store is not this broker's own ({why}): starting afresh");
            self.sup.forget();
            return false;
        }
        let writer = match Writer::resume(port, &path) {
            Ok(w) => w,
            Err(e) => {
                tracing::warn!("the port in the fd store cannot be taken back ({e}): starting afresh");
                self.sup.forget();
                return false;
            }
        };
        let epoch = writer.epoch();
        let checked = request::check(&stored.request, &self.cfg.limits);
        let lfi = writer.last_frame_index();
        let why_not = if lfi > MAX_RESUMED_FRAME {
            Some(format!("its last frame index {lfi} is past {MAX_RESUMED_FRAME} (2^53)"))
        } else if stored.config != supervise::config_fingerprint() {
            Some("bassd was restarted with another command line".to_owned())
        } else if stored.epoch != epoch {
            Some(format!("the record names epoch {}, the port has {epoch}", stored.epoch))
        } else {
            match &checked {
                Err(msg) => Some(format!("its request is refused now: {msg}")),
                Ok(c) if c.geometry != *writer.geometry() => {
                    Some("its request does not describe the port's geometry".to_owned())
                }
                Ok(c) if matches!(c.device, DeviceKind::File { .. }) => {
                    Some("a replayed recording starts again at its own frame indices".to_owned())
                }
                Ok(_) => None,
            }
        };
        let checked = match (why_not, checked) {
            (None, Ok(c)) => c,
            (why, _) => {
                let why = why.unwrap_or_default();
                tracing::info!(
                    epoch,
                    "not resuming the acquisition of {:?}: {why}; a new one starts",
                    stored.request.device
                );
                // Its readers are told (Restarted), and the next epoch passes this one.
                writer.set_state(State::Superseded, error_code::NONE, "");
                self.handed_epoch = self.handed_epoch.max(Some(epoch));
                self.sup.forget();
                return false;
            }
        };
        let due_ns = writer.next_frame_due_ns().unwrap_or_else(monotonic_ns);
        let job = match self.spawn_open(&checked) {
            Ok(j) => j,
            Err(e) => {
                let msg = format!("cannot start the device open thread to resume: {e}");
                tracing::error!("{msg}");
                writer.set_state(State::Error, error_code::INTERNAL, &msg);
                self.sup.forget();
                return true;
            }
        };
        tracing::info!(
            epoch,
            last_frame = writer.last_frame_index(),
            device = %stored.request.device,
            "taking back the port from the fd store: resuming the acquisition"
        );
        self.opening = Some(Opening {
            req: stored.request,
            checked,
            pending: NextPort::Resumed { writer, due_ns },
            requested_ns: monotonic_ns(),
            freed: true,
            reply_to: None,
            job,
        });
        true
    }

    /// Hands the running acquisition's port to the fd store (when the broker uses one); false
    /// when the store does not hold it (nothing can take it back).
    pub(super) fn store_port(
        &mut self,
        fd: std::os::fd::OwnedFd,
        request: &AcquireRequest,
        epoch: u64,
    ) -> bool {
        let stored = Stored {
            version: 1,
            name: self.cfg.name.clone(),
            config: supervise::config_fingerprint(),
            request: request.clone(),
            epoch,
        };
        self.sup.store(fd, &stored)
    }
}

/// The one-line STATUS= the service manager shows (`systemctl status bassd`).
pub(super) fn status_line(s: &Status) -> String {
    match State::from_u32(s.state) {
        Some(State::Capturing) => format!(
            "capturing {} at {} Hz, {} ch; frame {}, epoch {}, {} overruns",
            s.device, s.sample_rate, s.channels, s.last_frame_index, s.epoch, s.xruns
        ),
        Some(State::Idle) if s.message.starts_with("waiting for device") => s.message.clone(),
        Some(State::Idle) => "idle: no acquisition".to_owned(),
        state => {
            let name = state.map_or("unknown state", State::name);
            if s.message.is_empty() {
                format!("{name}: {}, frame {}, epoch {}", s.device, s.last_frame_index, s.epoch)
            } else {
                format!("{name}: {}", s.message)
            }
        }
    }
}
