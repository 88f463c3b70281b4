//! The Acquire path of the broker: the request checks and their refusal messages, the
//! pin budget for superseded ports, the device open, and the switch from the running
//! acquisition's port to the new one (built under a temporary name, renamed into place).
//!
//! Everything that can fail happens before the running acquisition or its port is touched;
//! the control loop that calls [`Broker::acquire`] is in [`super`].

use bassclient::control::{AcquireRequest, Acquired, ErrorKind, Reply};
use bassclient::format::error_code;
use bassclient::portfile::mib;
use bassclient::sys::monotonic_ns;
use bassclient::PortParams;

use super::{Broker, STOP_TIMEOUT};
use crate::capture::{Acquisition, CaptureParams};
use crate::device::{self, alsa, sim::SimDevice, Capture};
use crate::pins::PIN_BUDGET_FACTOR;
use crate::request::{self, DeviceKind};

impl Broker {
    /// What a failed Acquire left in place, for its error message.
    fn unchanged(&self) -> String {
        match self.current.as_ref().map(|a| a.port.info()) {
            None => "no port was created or changed".into(),
            Some(Ok(i)) => format!(
                "the port is unchanged (epoch {}, {}, last frame {})",
                i.epoch,
                i.state.map_or("unknown state".into(), |s| format!("{s:?}").to_lowercase()),
                i.last_frame_index
            ),
            Some(Err(e)) => format!("the port was not touched (it cannot be read: {e})"),
        }
    }

    /// Acquire. Everything that can fail is done before the running acquisition or its port
    /// is touched: the request is checked, the new port is built and allocated under a
    /// temporary name, the device is opened and configured. Only then is the old capture
    /// stopped and the new port renamed into place. A failed Acquire therefore leaves the
    /// old port exactly as it was (same epoch, frames and state) and says why.
    ///
    /// One exception: a device that is busy while an acquisition runs may be busy because
    /// the running acquisition holds it (an ALSA hw device opens once). Then the running
    /// capture is stopped (its port keeps its window, state stopped) and the open retried
    /// once; if that fails too, the old port stays stopped, with its epoch and frames.
    pub(super) fn acquire(&mut self, r: &AcquireRequest, peer_uid: u32) -> Reply {
        let requested_ns = monotonic_ns();
        let checked = match request::check(r, self.cfg.max_port_bytes, &self.cfg.limits) {
            Ok(c) => c,
            Err(msg) => {
                tracing::warn!("Acquire refused (nothing changed): {msg}");
                return Reply::error(ErrorKind::InvalidArgument, &msg);
            }
        };
        if let Err(msg) = self.cfg.policy.check(&r.device, device::list) {
            tracing::warn!("Acquire refused by the device policy (nothing changed): {msg}");
            return Reply::error(ErrorKind::Permission, &msg);
        }
        let g = checked.geometry.clone();
        let params = PortParams { geometry: g.clone(), device: r.device.clone(), group: self.cfg.group };
        if let Err(msg) = self.check_pin_budget(peer_uid, g.layout().map_or(0, |l| l.total_size)) {
            tracing::warn!(uid = peer_uid, "{msg}");
            return Reply::error(ErrorKind::InvalidArgument, &msg);
        }
        let pending = match crate::handoff::prepare(&self.cfg, &params, self.current.as_ref()) {
            Ok(p) => p,
            Err(e) => {
                let msg = format!("Acquire refused: cannot create the port: {e}; {}", self.unchanged());
                tracing::error!("{msg}");
                return Reply::error(ErrorKind::Internal, &msg);
            }
        };
        let mut opened = open_device(&checked.device, &g, checked.format);
        let mut freed = false;
        if opened.as_ref().is_err_and(|e| e.busy) && self.current.as_ref().is_some_and(Acquisition::running) {
            if let Some(old) = self.current.as_mut() {
                tracing::info!(device = %r.device, "device busy: stopping the running acquisition to retry");
                old.stop(STOP_TIMEOUT);
                freed = true;
            }
            opened = open_device(&checked.device, &g, checked.format);
        }
        let dev = match opened {
            Ok(d) => d,
            Err(e) => {
                let kept = self.unchanged();
                let msg = if freed {
                    format!(
                        "{} (after stopping the running acquisition, which may have held the device); \
                         its port keeps its window: {kept}",
                        e.message
                    )
                } else {
                    format!("{}; {kept}", e.message)
                };
                tracing::error!("Acquire failed: {msg}");
                return Reply::error(ErrorKind::Device, &msg);
            }
        };
        // The switch: the old capture stops, then the new port takes the name.
        if let Some(old) = self.current.as_mut() {
            old.stop(STOP_TIMEOUT);
        }
        let writer = match pending.commit() {
            Ok(w) => w,
            Err(e) => {
                // The rename failed: the old acquisition stays current (stopped, its window kept).
                let msg = format!("cannot put the new port in place: {e}; {}", self.unchanged());
                tracing::error!("{msg}");
                return Reply::error(ErrorKind::Internal, &msg);
            }
        };
        if let Some(old) = self.current.take() {
            crate::handoff::supersede(&old);
            if let Ok(f) = old.port.file().try_clone() {
                self.pins.add(f, old.port.size());
            }
        }
        let epoch = writer.epoch();
        let port_path = writer.path().display().to_string();
        let format = dev.format_name();
        let cp = CaptureParams {
            geometry: g.clone(),
            rt_priority: self.cfg.rt_priority,
            requested_ns,
            stall_ms: self.cfg.stall_ms,
        };
        match Acquisition::start(writer, dev, &r.device, cp) {
            Ok(a) => {
                tracing::info!(
                    epoch,
                    device = %r.device,
                    format,
                    rate = g.sample_rate,
                    frames_per_chunk = g.frames_per_chunk,
                    chunks_on_port = g.chunks_on_port,
                    channels = g.channels,
                    "acquisition started"
                );
                self.current = Some(a);
                Reply::Acquired(Acquired { epoch, port: port_path.into(), format: format.into() })
            }
            Err(e) => Reply::error(ErrorKind::Internal, &format!("cannot start the capture thread: {e}")),
        }
    }

    /// The bound on shared memory other users can make the broker's ports pin: for an
    /// Acquire of a client that is neither the broker's user nor root, the superseded ports
    /// still mapped by readers, the current port (which this Acquire would supersede) and
    /// the new one must fit in `PIN_BUDGET_FACTOR x --max-port-bytes`.
    fn check_pin_budget(&mut self, peer_uid: u32, new_bytes: u64) -> Result<(), String> {
        let pinned = self.pins.prune();
        if peer_uid == self.own_uid || peer_uid == 0 {
            return Ok(());
        }
        let current = self.current.as_ref().map_or(0, |a| a.port.size());
        let budget = PIN_BUDGET_FACTOR.saturating_mul(self.cfg.max_port_bytes);
        let total = pinned + current + new_bytes;
        if total > budget {
            return Err(format!(
                "Acquire refused: {} superseded port(s) still mapped by readers pin {}, the current port \
                 holds {} and this one needs {}: {} in all, over the {} that clients other than the \
                 broker's user may make its ports pin ({PIN_BUDGET_FACTOR} x --max-port-bytes); close \
                 the readers of old acquisitions, or ask the broker's user to acquire; {}",
                self.pins.len(),
                mib(pinned),
                mib(current),
                mib(new_bytes),
                mib(total),
                mib(budget),
                self.unchanged()
            ));
        }
        Ok(())
    }
}

/// Opens (and configures) the device of an Acquire.
fn open_device(
    kind: &DeviceKind,
    g: &bassclient::Geometry,
    format: Option<crate::convert::SampleFormat>,
) -> Result<Box<dyn Capture>, alsa::OpenError> {
    match kind {
        DeviceKind::Sim(kind) => {
            Ok(Box::new(SimDevice::new(*kind, g.sample_rate, g.channels, g.frames_per_chunk)))
        }
        DeviceKind::File { path, mode } => {
            device::file::open(path, *mode, g.sample_rate, g.channels, g.frames_per_chunk)
                .map(|d| Box::new(d) as Box<dyn Capture>)
                .map_err(|message| alsa::OpenError { code: error_code::CONFIG, message, busy: false })
        }
        DeviceKind::Alsa(name) => alsa::open(&alsa::OpenParams {
            name,
            rate: g.sample_rate,
            channels: g.channels,
            period: g.frames_per_chunk,
            format,
        })
        .map(|d| Box::new(d) as Box<dyn Capture>),
    }
}
