//! The Acquire path of the broker: the request checks and their refusal messages, the
//! pin budget for superseded ports, the device open (on a worker thread, bounded in time:
//! [`super::opening`]), and the switch from the running acquisition's port to the new one
//! (built under a temporary name, renamed into place).
//!
//! Everything that can fail happens before the running acquisition or its port is touched;
//! the control loop that calls [`Broker::acquire`] and [`Broker::poll_open`] is in [`super`].

use std::sync::atomic::Ordering;

use bassport::control::{AcquireRequest, Acquired, ErrorKind, Reply};
use bassport::format::{error_code, State};
use bassport::portfile::mib;
use bassport::sys::monotonic_ns;
use bassport::{PortParams, Writer};

use super::opening::{answer, NextPort, OpenJob, Opened, Opening, Parked, Poll, MAX_STUCK_OPENS};
use super::{Broker, STOP_TIMEOUT};
use crate::capture::multi::FollowerSpec;
use crate::capture::{Acquisition, CaptureParams};
use crate::device::{self, alsa, alsa::OpenError, field::FieldDevice, sim::SimDevice, Capture};
use crate::pins::PIN_BUDGET_FACTOR;
use crate::request::{self, Checked, DeviceKind};

impl Broker {
    /// What a failed Acquire left in place, for its error message.
    fn unchanged(&self) -> String {
        match self.current.as_ref().map(|a| a.port.info()) {
            None => "no port was created or changed".into(),
            Some(Ok(i)) => format!(
                "the port is unchanged (epoch {}, {}, last frame {})",
                i.epoch,
                i.state.map_or("unknown state", State::name),
                i.last_frame_index
            ),
            Some(Err(e)) => format!("the port was not touched (it cannot be read: {e})"),
        }
    }

    /// Acquire, first half: the request is checked and the new port is built and allocated
    /// under a temporary name; then the device open starts on a worker thread
    /// ([`super::opening`]) and the request's connection is parked. Returns the reply of a
    /// refusal, or None once the open is under way ([`Broker::poll_open`] finishes it).
    ///
    /// Everything that can fail is done before the running acquisition or its port is
    /// touched: the request is checked, the new port is built and allocated under a
    /// temporary name, the device is opened and configured (within `--open-timeout-ms`).
    /// Only then is the old capture stopped and the new port renamed into place. A failed
    /// Acquire therefore leaves the old port exactly as it was (same epoch, frames and state)
    /// and says why.
    ///
    /// One exception: a device that is busy while an acquisition runs may be busy because
    /// the running acquisition holds it (an ALSA hw device opens once). Then the running
    /// capture is stopped (its port keeps its window, state stopped) and the open retried
    /// once; if that fails too, the old port stays stopped, with its epoch and frames.
    pub(super) fn acquire(
        &mut self,
        r: &AcquireRequest,
        peer_uid: u32,
        reply_to: Option<Parked>,
    ) -> Option<Reply> {
        let requested_ns = monotonic_ns();
        if let Some(op) = &self.opening {
            let msg = format!(
                "Acquire refused: another Acquire is opening device {:?} (for {} ms, at most {} ms); \
                 wait for its reply, or send Stop to cancel it; {}",
                op.req.device,
                op.job.elapsed_ms(requested_ns),
                self.cfg.open_timeout.as_millis(),
                self.unchanged()
            );
            tracing::warn!("{msg}");
            return Some(Reply::error(ErrorKind::Device, &msg));
        }
        let stuck = self.open_threads.load(Ordering::Acquire);
        if stuck >= MAX_STUCK_OPENS {
            let msg = format!(
                "Acquire refused: {stuck} earlier device opens never returned (their threads are still \
                 blocked in the devices; is a sound server stopped?); restart bassd once the device \
                 is back; {}",
                self.unchanged()
            );
            tracing::error!("{msg}");
            return Some(Reply::error(ErrorKind::Device, &msg));
        }
        let checked = match request::check(r, &self.cfg.limits) {
            Ok(c) => c,
            Err(msg) => {
                tracing::warn!("Acquire refused (nothing changed): {msg}");
                return Some(Reply::error(ErrorKind::InvalidArgument, &msg));
            }
        };
        let names = std::iter::once(&r.device).chain(r.followers.iter().map(|f| &f.device));
        if let Some(msg) = names.filter_map(|d| self.cfg.policy.check(d, device::list).err()).next() {
            tracing::warn!("Acquire refused by the device policy (nothing changed): {msg}");
            return Some(Reply::error(ErrorKind::Permission, &msg));
        }
        let g = checked.geometry.clone();
        let params = PortParams { geometry: g.clone(), device: r.device.clone(), group: self.cfg.group };
        if let Err(msg) = self.check_pin_budget(peer_uid, g.layout().map_or(0, |l| l.total_size)) {
            tracing::warn!(uid = peer_uid, "{msg}");
            return Some(Reply::error(ErrorKind::InvalidArgument, &msg));
        }
        let after = self.current.as_ref().map(|a| a.port.epoch()).or(self.handed_epoch);
        let resumable = self.sup.restart_grace_ms() > 0;
        let pending = match crate::handoff::prepare(&self.cfg, &params, after, resumable) {
            Ok(p) => p,
            // No room for the port where ports live: a refusal like a window over
            // --max-port-bytes (the message names the size needed and the space there is).
            Err(e) if is_no_space(&e) => {
                let msg = format!("Acquire refused: {e}; {}", self.unchanged());
                tracing::warn!("{msg}");
                return Some(Reply::error(ErrorKind::InvalidArgument, &msg));
            }
            Err(e) => {
                let msg = format!("Acquire refused: cannot create the port: {e}; {}", self.unchanged());
                tracing::error!("{msg}");
                return Some(Reply::error(ErrorKind::Internal, &msg));
            }
        };
        let job = match self.spawn_open(&checked) {
            Ok(j) => j,
            Err(e) => {
                let msg = format!(
                    "Acquire refused: cannot start the device open thread: {e}; {}",
                    self.unchanged()
                );
                tracing::error!("{msg}");
                return Some(Reply::error(ErrorKind::Internal, &msg));
            }
        };
        tracing::debug!(device = %r.device, "opening the device");
        let pending = NextPort::New(pending);
        self.opening =
            Some(Opening { req: r.clone(), checked, pending, requested_ns, freed: false, reply_to, job });
        // The reply comes from poll_open, when the worker's eventfd wakes the loop (or the
        // bound passes).
        None
    }

    pub(super) fn spawn_open(&self, checked: &Checked) -> std::io::Result<OpenJob> {
        let (kind, mut g, format) = (checked.device.clone(), checked.geometry.clone(), checked.format);
        g.channels = checked.master_channels;
        OpenJob::spawn(move || open_device(&kind, &g, format), self.cfg.open_timeout, &self.open_threads)
    }

    /// Finishes the pending Acquire if its device open returned or ran out of time (called
    /// by the control loop on every wake-up), and sends its reply.
    pub(super) fn poll_open(&mut self) {
        let Some(op) = &self.opening else { return };
        let now = monotonic_ns();
        let opened = match op.job.poll(now) {
            Poll::Pending => return,
            Poll::Done(r) => r,
            Poll::TimedOut => {
                let waited = op.job.elapsed_ms(now);
                let Some(op) = self.opening.take() else { return };
                let msg = format!(
                    "device {:?}: the open did not return within {waited} ms (bassd --open-timeout-ms {}): \
                     is its sound server running, or stopped? The open is left behind (the device is \
                     closed if it ever returns); {}",
                    op.req.device,
                    self.cfg.open_timeout.as_millis(),
                    self.unchanged()
                );
                tracing::error!("Acquire failed: {msg}");
                if op.reply_to.is_none() {
                    self.last_open_failure = Some(msg.clone());
                }
                answer(op.reply_to, &Reply::error(ErrorKind::Device, &msg));
                return;
            }
        };
        let Some(op) = self.opening.take() else { return };
        if let Some((to, reply)) = self.finish_acquire(op, opened) {
            if let (None, Reply::Error { message, .. }) = (&to, &reply) {
                self.last_open_failure = Some(message.clone());
            }
            answer(to, &reply);
        }
    }

    /// Cancels the pending Acquire (Stop, shutdown): its client gets an error saying `why`.
    /// Returns the device it was opening.
    pub(super) fn cancel_open(&mut self, why: &str) -> Option<String> {
        let op = self.opening.take()?;
        let msg = format!(
            "the Acquire of {:?} was cancelled {why} while its device was opening (after {} ms); {}",
            op.req.device,
            op.job.elapsed_ms(monotonic_ns()),
            self.unchanged()
        );
        tracing::warn!("{msg}");
        answer(op.reply_to, &Reply::error(ErrorKind::Device, &msg));
        Some(op.req.device)
    }

    /// Acquire, second half: the device open returned. Returns who gets which reply, or None
    /// when the open was started again (a busy device, after stopping the running capture).
    fn finish_acquire(&mut self, op: Opening, opened: Opened) -> Option<(Option<Parked>, Reply)> {
        if !op.freed
            && opened.as_ref().is_err_and(|e| e.busy)
            && self.current.as_ref().is_some_and(Acquisition::running)
        {
            return self.retry_busy(op);
        }
        let dev = match opened {
            Ok(d) => d,
            Err(e) => return Some(self.open_failed(op, e)),
        };
        let (reply_to, r, checked, requested_ns) = (op.reply_to, op.req, op.checked, op.requested_ns);
        let (writer, resume_from_ns) = match self.switch_port(op.pending) {
            Ok(w) => w,
            Err(msg) => return Some((reply_to, Reply::error(ErrorKind::Internal, &msg))),
        };
        let cp = CaptureParams {
            geometry: checked.geometry.clone(),
            rt_priority: self.cfg.rt_priority,
            requested_ns,
            stall_ms: self.cfg.stall_ms,
            resume_from_ns,
            master_channels: checked.master_channels,
            followers: follower_specs(&checked),
        };
        Some((reply_to, self.start_capture(writer, dev, &r, cp)))
    }

    /// The device is busy, most likely held by the running capture: stops it and opens the
    /// device again (None: the open runs again), or says why it cannot.
    fn retry_busy(&mut self, mut op: Opening) -> Option<(Option<Parked>, Reply)> {
        if let Some(old) = self.current.as_mut() {
            tracing::info!(device = %op.req.device, "device busy: stopping the running acquisition to retry");
            old.stop(STOP_TIMEOUT);
        }
        op.freed = true;
        match self.spawn_open(&op.checked) {
            Ok(j) => {
                op.job = j;
                self.opening = Some(op);
                None
            }
            Err(e) => {
                let msg = format!("cannot start the device open thread: {e}; {}", self.unchanged());
                Some((op.reply_to, Reply::error(ErrorKind::Internal, &msg)))
            }
        }
    }

    /// The device did not open: the reply says why and what was kept; a resumed acquisition
    /// that cannot go on tells its readers.
    fn open_failed(&mut self, op: Opening, e: OpenError) -> (Option<Parked>, Reply) {
        let kept = self.unchanged();
        let msg = if op.freed {
            format!(
                "{} (after stopping the running acquisition, which may have held the device); \
                 its port keeps its window: {kept}",
                e.message
            )
        } else {
            format!("{}; {kept}", e.message)
        };
        tracing::error!("Acquire failed: {msg}");
        if let NextPort::Resumed { writer, .. } = &op.pending {
            // The resumed acquisition cannot go on: its readers are told why.
            writer.set_state(State::Error, e.code, &msg);
            self.sup.forget();
        }
        (op.reply_to, Reply::error(ErrorKind::Device, &msg))
    }

    /// The switch: the old capture stops (its port goes from capturing straight to superseded:
    /// its readers see no Stopped), then the new port takes the name. Returns the new port's
    /// writer and, for a port taken back, where its timeline goes on; Err when the new port
    /// cannot be put in place (the old acquisition then stays current, stopped, its window
    /// kept).
    fn switch_port(&mut self, pending: NextPort) -> Result<(Writer, Option<u64>), String> {
        if let Some(old) = self.current.as_mut() {
            old.halt(STOP_TIMEOUT);
        }
        let (writer, resume_from_ns) = match pending {
            NextPort::New(p) => match p.commit() {
                Ok(w) => (w, None),
                Err(e) => {
                    if let Some(old) = self.current.as_mut() {
                        old.stop(STOP_TIMEOUT);
                    }
                    let msg = format!("cannot put the new port in place: {e}; {}", self.unchanged());
                    tracing::error!("{msg}");
                    return Err(msg);
                }
            },
            NextPort::Resumed { writer, due_ns } => (writer, Some(due_ns)),
        };
        if let Some(old) = self.current.take() {
            crate::handoff::supersede(&old);
            if let Ok(f) = old.port.file().try_clone() {
                self.pins.add(f, old.port.size());
            }
        }
        Ok((writer, resume_from_ns))
    }

    /// Starts the capture thread on the new port: the acquisition becomes current, its port
    /// goes to the service manager's store (or its readers are told no successor can take it
    /// back).
    fn start_capture(
        &mut self,
        writer: Writer,
        dev: Box<dyn Capture>,
        r: &AcquireRequest,
        cp: CaptureParams,
    ) -> Reply {
        let g = cp.geometry.clone();
        let epoch = writer.epoch();
        let port_path = writer.path().display().to_string();
        let format = dev.format_name();
        let devices = 1 + cp.followers.len() as u32;
        writer.set_restart_grace_ms(self.sup.restart_grace_ms());
        let store_fd =
            writer.writable_fd().map_err(|e| tracing::warn!("no descriptor for the fd store: {e}")).ok();
        match Acquisition::start(writer, dev, &r.device, cp) {
            Ok(a) => {
                let stored = store_fd.is_some_and(|fd| self.store_port(fd, r, epoch));
                if !stored {
                    // Not in the store (none used, or it refused): no successor can take this
                    // port back, so its readers are not kept waiting for one.
                    a.set_restart_grace_ms(0);
                }
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
                Reply::Acquired(Acquired { epoch, port: port_path.into(), format: format.into(), devices })
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
        let budget = PIN_BUDGET_FACTOR.saturating_mul(self.cfg.limits.max_port_bytes);
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

/// Whether creating the port failed for want of space in its file system (ENOSPC).
fn is_no_space(e: &bassport::Error) -> bool {
    matches!(e, bassport::Error::Io { source, .. } if source.raw_os_error() == Some(libc::ENOSPC))
}

/// Opens (and configures) the device of an Acquire (on a worker thread: it may block).
fn open_device(
    kind: &DeviceKind,
    g: &bassport::Geometry,
    format: Option<crate::convert::SampleFormat>,
) -> Result<Box<dyn Capture>, alsa::OpenError> {
    match kind {
        DeviceKind::Sim(kind) => {
            Ok(Box::new(SimDevice::new(*kind, g.sample_rate, g.channels, g.frames_per_chunk)))
        }
        DeviceKind::Field(p) => {
            Ok(Box::new(FieldDevice::new(p.clone(), g.sample_rate, g.channels, g.frames_per_chunk)))
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

/// The followers of an Acquire, each opened by its own capture thread (a follower that does
/// not open is retried, the acquisition going on with the master: docs/multi-device.md).
fn follower_specs(checked: &Checked) -> Vec<FollowerSpec> {
    checked
        .followers
        .iter()
        .map(|f| {
            let (kind, format) = (f.device.clone(), checked.format);
            let mut g = checked.geometry.clone();
            g.channels = f.channels;
            FollowerSpec {
                name: f.name.clone(),
                channels: f.channels as usize,
                open: Box::new(move || open_device(&kind, &g, format).map_err(|e| e.message)),
            }
        })
        .collect()
}
