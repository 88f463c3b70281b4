//! The broker's control loop: the instance lock, the control socket, peer checks, request
//! dispatch (ListDevices, Acquire, Stop, Status), the stall watchdog and the signals.
//!
//! One thread runs everything here with `poll` over the listening socket, a signalfd and
//! the client connections; the capture runs on its own thread (see [`crate::capture`]).

use std::fs::File;
use std::io::Write;
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context};
use bassclient::control::{self, AcquireRequest, ErrorKind, Message, Request, Status, PROTOCOL_MAJOR};
use bassclient::format::{error_code, State};
use bassclient::paths;
use bassclient::reader::Port;
use bassclient::sys::monotonic_ns;
use bassclient::{PortParams, Writer};

use crate::capture::{Acquisition, CaptureParams};
use crate::device::{self, alsa, sim::SimDevice, Capture};
use crate::os;
use crate::pins::{Ledger, PIN_BUDGET_FACTOR};
use crate::request::{self, DeviceKind};
use bassclient::portfile::mib;

/// Broker configuration (command line of `bassd`).
#[derive(Clone, Debug)]
pub struct Config {
    /// Broker name (port `bass-NAME.port`, socket `bass-NAME.sock`).
    pub name: String,
    /// Group allowed to control the broker and read its port, besides its own user.
    pub group: Option<u32>,
    /// Largest port file an Acquire may create (bytes).
    pub max_port_bytes: u64,
    /// SCHED_FIFO priority of the capture thread (0 = none).
    pub rt_priority: i32,
    /// Stall watchdog threshold in ms (0 = max(4 chunks, 250 ms)).
    pub stall_ms: u64,
    /// An Acquire to run at start-up.
    pub acquire: Option<AcquireRequest>,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            name: paths::DEFAULT_NAME.into(),
            group: None,
            max_port_bytes: DEFAULT_MAX_PORT_BYTES,
            rt_priority: 70,
            stall_ms: 0,
            acquire: None,
        }
    }
}

/// Default memory cap of a port: 512 MiB (about 23 minutes of 48 kHz stereo).
pub const DEFAULT_MAX_PORT_BYTES: u64 = 512 << 20;
/// How long a Stop waits for the capture thread before leaving it behind.
const STOP_TIMEOUT: Duration = Duration::from_secs(2);
/// Period of the stall watchdog.
const TICK: Duration = Duration::from_millis(25);
/// A gap between two watchdog ticks longer than this means the broker was frozen.
const FROZEN_NS: u64 = 200_000_000;
/// How often superseded ports are checked for remaining readers.
const PRUNE_NS: u64 = 1_000_000_000;
/// Most control connections open at once.
const MAX_CLIENTS: usize = 128;

/// The broker's state.
pub struct Broker {
    cfg: Config,
    current: Option<Acquisition>,
    last_tick_ns: u64,
    /// Superseded ports readers may still map.
    pins: Ledger,
    last_prune_ns: u64,
    own_uid: u32,
}

impl Broker {
    /// A broker with no acquisition.
    pub fn new(cfg: Config) -> Broker {
        Broker {
            cfg,
            current: None,
            last_tick_ns: monotonic_ns(),
            pins: Ledger::default(),
            last_prune_ns: 0,
            own_uid: os::euid(),
        }
    }

    /// Answers one request of the broker's own user.
    pub fn handle(&mut self, req: Request) -> Message {
        self.handle_as(req, self.own_uid)
    }

    /// Answers one request of a client running as `peer_uid`.
    pub fn handle_as(&mut self, req: Request, peer_uid: u32) -> Message {
        match req {
            Request::ListDevices => control::devices_to_message(&device::list()),
            Request::Status => self.status().to_message(),
            Request::Stop => self.stop(),
            Request::Acquire(r) => self.acquire(&r, peer_uid),
        }
    }

    fn status(&self) -> Status {
        let mut s = Status {
            broker_pid: std::process::id(),
            broker_version: env!("CARGO_PKG_VERSION").into(),
            ..Default::default()
        };
        let Some(a) = &self.current else {
            s.state = State::Idle as u32;
            s.message = "no acquisition since the broker started".into();
            return s;
        };
        s.format = a.format.clone();
        s.port = a.port.path().display().to_string();
        match a.port.info() {
            Ok(i) => {
                s.state = i.state.map_or(State::Error as u32, |st| st as u32);
                s.error_code = i.error_code;
                s.sample_rate = i.geometry.sample_rate;
                s.frames_per_chunk = i.geometry.frames_per_chunk;
                s.chunks_on_port = i.geometry.chunks_on_port;
                s.channels = i.geometry.channels;
                s.epoch = i.epoch;
                s.last_frame_index = i.last_frame_index;
                s.xruns = i.xruns;
                s.gap_frames = i.gap_frames;
                s.chunks_published = i.chunks_published;
                s.rate_estimate_hz = i.rate_estimate_hz;
                s.device = i.device;
                s.message = i.message;
            }
            Err(e) => {
                s.state = State::Error as u32;
                s.error_code = error_code::INTERNAL;
                s.message = format!("cannot read the port: {e}");
            }
        }
        s
    }

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
    fn acquire(&mut self, r: &AcquireRequest, peer_uid: u32) -> Message {
        let requested_ns = monotonic_ns();
        let checked = match request::check(r, self.cfg.max_port_bytes) {
            Ok(c) => c,
            Err(msg) => {
                tracing::warn!("Acquire refused (nothing changed): {msg}");
                return Message::error(ErrorKind::InvalidArgument, &msg);
            }
        };
        let g = checked.geometry.clone();
        let params = PortParams { geometry: g.clone(), device: r.device.clone(), group: self.cfg.group };
        if let Err(msg) = self.check_pin_budget(peer_uid, g.layout().map_or(0, |l| l.total_size)) {
            tracing::warn!(uid = peer_uid, "{msg}");
            return Message::error(ErrorKind::InvalidArgument, &msg);
        }
        let pending = match Writer::prepare(&self.cfg.name, &params) {
            Ok(p) => p,
            Err(e) => {
                let msg = format!("Acquire refused: cannot create the port: {e}; {}", self.unchanged());
                tracing::error!("{msg}");
                return Message::error(ErrorKind::Internal, &msg);
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
                return Message::error(ErrorKind::Device, &msg);
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
                return Message::error(ErrorKind::Internal, &msg);
            }
        };
        if let Some(old) = self.current.take() {
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
                Message::new("ok").with("epoch", epoch).with("port", port_path).with("format", format)
            }
            Err(e) => Message::error(ErrorKind::Internal, &format!("cannot start the capture thread: {e}")),
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

    /// Stop: ends the capture (the port keeps its window, state stopped); an acquisition
    /// that had ended on an error is moved out of the error state. The reply's `message`
    /// says what was done.
    fn stop(&mut self) -> Message {
        let Some(a) = self.current.as_mut() else {
            return Message::new("ok")
                .with("message", "nothing to stop: no acquisition since the broker started");
        };
        let before = a.port.info().ok().and_then(|i| i.state);
        a.stop(STOP_TIMEOUT);
        let last = a.port.info().map(|i| i.last_frame_index).unwrap_or(0);
        let msg = match a.clear_error() {
            Some(err) => format!("cleared the error state (it was: {err}); state stopped, last frame {last}"),
            None if before == Some(State::Stopped) => format!("already stopped at frame {last}"),
            None => format!("stopped at frame {last}"),
        };
        tracing::info!(device = %a.device, "{msg}");
        Message::new("ok").with("message", msg)
    }

    /// Runs the stall watchdog once.
    ///
    /// If the broker itself did not run for a while (SIGSTOP, a suspended machine, heavy
    /// overload), the silence is ours, not the device's: the device gets a fresh grace
    /// period instead of being declared stalled.
    pub fn tick(&mut self) {
        let now = monotonic_ns();
        let late = now.saturating_sub(self.last_tick_ns) > FROZEN_NS;
        self.last_tick_ns = now;
        // Superseded ports: our own descriptor must not keep one alive once its readers left.
        if !self.pins.is_empty() && now.saturating_sub(self.last_prune_ns) > PRUNE_NS {
            self.last_prune_ns = now;
            self.pins.prune();
        }
        if let Some(a) = &self.current {
            if late {
                a.rebase_watchdog(now);
            } else {
                a.check_stall(now);
            }
        }
    }

    /// Stops everything (on SIGTERM / SIGINT).
    pub fn shutdown(&mut self) {
        if let Some(a) = self.current.as_mut() {
            a.stop(STOP_TIMEOUT);
        }
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

/// Whether `peer` may control a broker running as `own_uid` with allowed group `group`.
pub fn peer_allowed(peer: &os::Peer, own_uid: u32, group: Option<u32>) -> bool {
    peer.uid == own_uid || peer.uid == 0 || group.is_some_and(|g| peer.gid == g || peer.groups.contains(&g))
}

/// The running daemon's files: lock, socket.
struct Files {
    _lock: File,
    socket: PathBuf,
}

impl Drop for Files {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.socket);
    }
}

fn take_instance(cfg: &Config) -> anyhow::Result<Files> {
    let dir = paths::runtime_dir();
    let socket = paths::socket_path(&cfg.name)?;
    let lock_path = dir.join(format!("bass-{}.lock", cfg.name));
    let Some(mut lock) =
        os::try_lock(&lock_path).with_context(|| format!("opening {}", lock_path.display()))?
    else {
        let pid = std::fs::read_to_string(&lock_path).unwrap_or_default();
        bail!(
            "a broker named {:?} is already running (pid {}, control socket {}); \
             stop it first or start this one with --name OTHER",
            cfg.name,
            pid.trim(),
            socket.display()
        );
    };
    lock.set_len(0)?;
    writeln!(lock, "{}", std::process::id())?;
    // We hold the lock, so any socket there was left by a broker that died: replace it.
    if socket.exists() {
        tracing::warn!("removing the stale control socket {} left by a previous broker", socket.display());
        std::fs::remove_file(&socket).with_context(|| format!("removing stale {}", socket.display()))?;
    }
    let port = paths::port_path(&cfg.name)?;
    if let Ok(p) = Port::open_path(&port) {
        if let Ok(i) = p.info() {
            if !i.writer_alive {
                tracing::warn!(
                    "port {} was left by a broker that died (pid {}); its readers see the writer gone, \
                     and the next Acquire replaces it",
                    port.display(),
                    i.writer_pid
                );
            }
        }
    }
    Ok(Files { _lock: lock, socket })
}

/// Runs the broker until SIGTERM / SIGINT.
pub fn run(cfg: Config) -> anyhow::Result<()> {
    // Block the termination signals before any thread exists, so only the signalfd sees them.
    let sigfd = os::signalfd_for_termination().context("setting up the signal handling")?;
    let files = take_instance(&cfg)?;
    let mode = if cfg.group.is_some() { 0o660 } else { 0o600 };
    let listener = os::listen_seqpacket(&files.socket, mode, cfg.group)
        .with_context(|| format!("listening on {}", files.socket.display()))?;
    tracing::info!(name = %cfg.name, socket = %files.socket.display(), pid = std::process::id(), "bassd ready");
    let own_uid = os::euid();
    let mut broker = Broker::new(cfg.clone());
    if let Some(r) = &cfg.acquire {
        let reply = broker.handle(Request::Acquire(r.clone()));
        if reply.verb != "ok" {
            tracing::error!("start-up Acquire failed: {}", reply.get("message").unwrap_or(""));
        }
    }
    let mut clients: Vec<OwnedFd> = Vec::new();
    loop {
        let mut fds = vec![os::pollin(listener.as_raw_fd()), os::pollin(sigfd.as_raw_fd())];
        fds.extend(clients.iter().map(|c| os::pollin(c.as_raw_fd())));
        os::poll(&mut fds, Some(TICK)).context("poll")?;
        broker.tick();
        if fds[1].revents != 0 {
            if let Some(sig) = os::read_signal(&sigfd) {
                tracing::info!(signal = sig, "terminating: stopping the capture");
                broker.shutdown();
                drop(files);
                return Ok(());
            }
        }
        // Client requests, then drop closed connections (indices from the back).
        let mut closed = Vec::new();
        for (i, c) in clients.iter().enumerate() {
            let rev = fds[2 + i].revents;
            if rev == 0 {
                continue;
            }
            if !serve_one(&mut broker, c) {
                closed.push(i);
            }
        }
        for i in closed.into_iter().rev() {
            clients.swap_remove(i);
        }
        if fds[0].revents != 0 {
            while let Some(c) = os::accept(listener.as_raw_fd()).context("accept")? {
                let fd = c.as_raw_fd();
                let _ = os::set_send_timeout(fd, Duration::from_secs(1));
                let allowed = match os::peer_credentials(fd) {
                    Ok(p) if peer_allowed(&p, own_uid, cfg.group) => true,
                    Ok(p) => {
                        tracing::warn!(
                            pid = p.pid,
                            uid = p.uid,
                            "refused a control connection (not our user or group)"
                        );
                        false
                    }
                    Err(e) => {
                        tracing::warn!("refused a control connection: SO_PEERCRED: {e}");
                        false
                    }
                };
                if !allowed {
                    let m = Message::error(
                        ErrorKind::Permission,
                        "permission denied: not the broker's user or group",
                    );
                    let _ = control::send_message(c.as_fd(), &m);
                    os::drain(fd);
                } else if clients.len() >= MAX_CLIENTS {
                    let m = Message::error(ErrorKind::Internal, "too many control connections");
                    let _ = control::send_message(c.as_fd(), &m);
                    os::drain(fd);
                } else {
                    clients.push(c);
                }
            }
        }
    }
}

/// Reads one request from `c` and answers it; false when the connection is finished.
fn serve_one(broker: &mut Broker, c: &OwnedFd) -> bool {
    let reply = match control::recv_message(c.as_fd()) {
        Ok(None) => return false,
        Ok(Some(m)) if m.major != PROTOCOL_MAJOR => Message::error(
            ErrorKind::Version,
            &format!(
                "this broker speaks control protocol {PROTOCOL_MAJOR}, the request is version {}",
                m.major
            ),
        ),
        Ok(Some(m)) => match Request::from_message(&m) {
            Ok(r) => {
                let uid = os::peer_credentials(c.as_raw_fd()).map_or(u32::MAX, |p| p.uid);
                broker.handle_as(r, uid)
            }
            Err(e) => Message::error(ErrorKind::Protocol, &e.to_string()),
        },
        Err(e) => Message::error(ErrorKind::Protocol, &e.to_string()),
    };
    control::send_message(c.as_fd(), &reply).is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peers_are_allowed_by_user_root_or_group() {
        let p = |uid, gid, groups: Vec<u32>| os::Peer { pid: 1, uid, gid, groups };
        assert!(peer_allowed(&p(1000, 1000, vec![]), 1000, None));
        assert!(peer_allowed(&p(0, 0, vec![]), 1000, None));
        assert!(!peer_allowed(&p(1001, 1001, vec![]), 1000, None));
        assert!(peer_allowed(&p(1001, 29, vec![]), 1000, Some(29)));
        assert!(peer_allowed(&p(1001, 1001, vec![4, 29]), 1000, Some(29)));
        assert!(!peer_allowed(&p(1001, 1001, vec![4]), 1000, Some(29)));
    }
}
