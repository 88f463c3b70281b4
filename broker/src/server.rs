//! The broker's control loop: the instance lock, the control socket, peer checks, request
//! dispatch (ListDevices, Acquire, Stop, Status), the stall watchdog and the signals.
//!
//! One thread runs everything here with `poll` over the listening socket, the signals' wake-up and
//! the client connections; the capture runs on its own thread (see [`crate::capture`]). The
//! Acquire path (checks, refusals, pin budget, device open, the port switch) is in server/acquire.rs;
//! the device open runs on a worker thread bounded by `--open-timeout-ms` (server/opening.rs),
//! so no device can stop this loop from answering, nor from ending on SIGTERM.

use std::os::fd::{AsFd, AsRawFd, BorrowedFd, OwnedFd};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use bassclient::control::{self, AcquireRequest, ErrorKind, Reply, Request, Status, WireError};
use bassclient::format::{error_code, State};
use bassclient::instance::{Instance, InstanceError};
use bassclient::paths;
use bassclient::reader::Port;
use bassclient::sys::monotonic_ns;

use crate::capture::Acquisition;
use crate::device;
use crate::os;
use crate::pins::Ledger;
use crate::policy::DevicePolicy;
use crate::request::Limits;

mod acquire;
mod opening;

pub use opening::{DEFAULT_OPEN_TIMEOUT, MAX_STUCK_OPENS};

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
    // --- issue 9/14 hardening (h-server): device policy, bounds, connection limits ---
    /// Which devices clients may name (default policy + `--allow-device` patterns).
    pub policy: DevicePolicy,
    /// Operator bounds on Acquire requests (`--min-chunk-us`, `--max-rate`, ...).
    pub limits: Limits,
    /// A control connection with no request for this long is closed (`--idle-timeout-ms`).
    pub idle_timeout: Duration,
    /// What holds the port (`--port-backing`; see crate::handoff).
    pub port_backing: bassclient::Backing,
    /// Longest wait for a device to open and configure (`--open-timeout-ms`).
    pub open_timeout: Duration,
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
            policy: DevicePolicy::default(),
            limits: Limits::default(),
            idle_timeout: DEFAULT_IDLE_TIMEOUT,
            port_backing: bassclient::Backing::File,
            open_timeout: DEFAULT_OPEN_TIMEOUT,
        }
    }
}

/// Default memory cap of a port: 512 MiB (about 23 minutes of 48 kHz stereo).
pub const DEFAULT_MAX_PORT_BYTES: u64 = 512 << 20;
/// How long a Stop waits for the capture thread before leaving it behind (a healthy one
/// stops within a poll slice; one stuck in a device never does). The control loop waits in
/// it, so it also bounds how late a SIGTERM arriving meanwhile is handled: 500 + 400 ms < 1 s.
const STOP_TIMEOUT: Duration = Duration::from_millis(500);
/// The same on SIGTERM: bassd ends within 1 s in every state (a thread stuck in a device is
/// left behind; the process exits).
const SHUTDOWN_STOP_TIMEOUT: Duration = Duration::from_millis(400);
/// Period of the stall watchdog.
const TICK: Duration = Duration::from_millis(25);
/// A gap between two watchdog ticks longer than this means the broker was frozen.
const FROZEN_NS: u64 = 200_000_000;
/// How often superseded ports are checked for remaining readers.
const PRUNE_NS: u64 = 1_000_000_000;
/// Most control connections open at once.
pub const MAX_CLIENTS: usize = 128;
/// Of those, how many only the broker's own user and root may take: members of `--group`
/// can hold at most `MAX_CLIENTS - RESERVED_CLIENTS`, so the operator can always get in.
pub const RESERVED_CLIENTS: usize = 8;
/// Default idle timeout of a control connection.
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(30);
/// How long the broker stops accepting after running out of descriptors.
const ACCEPT_BACKOFF: Duration = Duration::from_millis(250);
/// Shortest interval between two "out of descriptors" log lines.
const EMFILE_LOG_EVERY_NS: u64 = 10_000_000_000;

/// The broker's state.
pub struct Broker {
    cfg: Config,
    current: Option<Acquisition>,
    last_tick_ns: u64,
    /// Superseded ports readers may still map.
    pins: Ledger,
    last_prune_ns: u64,
    own_uid: u32,
    /// The Acquire whose device is opening, if any.
    opening: Option<opening::Opening>,
    /// Device-open threads alive (stuck ones included).
    open_threads: Arc<AtomicUsize>,
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
            opening: None,
            open_threads: Arc::new(AtomicUsize::new(0)),
        }
    }

    /// Answers one request of a client running as `peer_uid`. An Acquire is answered later
    /// (None) once its device open is under way: the reply goes to `reply_to` (None: the
    /// start-up Acquire, whose outcome is logged).
    fn handle_as(&mut self, req: Request, peer_uid: u32, reply_to: Option<opening::Parked>) -> Option<Reply> {
        Some(match req {
            Request::ListDevices => Reply::Devices { devices: device::list() },
            Request::Status => Reply::Status(self.status()),
            Request::Stop => self.stop(),
            Request::Acquire(r) => return self.acquire(&r, peer_uid, reply_to),
            Request::OpenPort => crate::handoff::not_on_a_socket(),
        })
    }

    /// The connection parked on the pending Acquire, if any.
    fn parked_conn(&self) -> Option<u64> {
        self.opening.as_ref().and_then(|o| o.reply_to.as_ref()).map(|p| p.id)
    }

    /// The pending device open's wake-up descriptor (-1: none, which poll ignores).
    fn open_wake_fd(&self) -> std::os::fd::RawFd {
        self.opening.as_ref().map_or(-1, |o| o.job.wake_fd())
    }

    fn status(&self) -> Status {
        let mut s = self.port_status();
        if let Some(op) = &self.opening {
            // An Acquire waits for its device: say so, and what the port does meanwhile.
            let now = monotonic_ns();
            let port = match self.current.as_ref().map(|a| a.port.info()) {
                None => "no port yet".to_owned(),
                Some(_) => format!(
                    "until it opens, the port (epoch {}) is {}",
                    s.epoch,
                    State::from_u32(s.state).map_or("unknown".into(), |st| format!("{st:?}").to_lowercase())
                ),
            };
            s.state = State::Starting as u32;
            s.error_code = error_code::NONE;
            s.message = format!(
                "opening device {:?} for an Acquire ({} ms so far, at most {} ms); {port}",
                op.req.device,
                op.job.elapsed_ms(now),
                self.cfg.open_timeout.as_millis()
            );
        }
        s
    }

    /// Status from the current port, with what the broker knows beyond it: a failure the
    /// capture recorded (written into a port that may have been cut, so readers may never see
    /// it), and a port file cut under the broker.
    fn port_status(&self) -> Status {
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
                // JSON has no NaN or infinity: a value the port cannot hold reads as "none yet".
                s.rate_estimate_hz = if i.rate_estimate_hz.is_finite() { i.rate_estimate_hz } else { 0.0 };
                s.device = i.device;
                s.message = i.message;
            }
            Err(e) => {
                s.state = State::Error as u32;
                s.error_code = error_code::INTERNAL;
                s.message = format!("cannot read the port: {e}");
            }
        }
        if let Some(cut) = port_cut(a) {
            s.state = State::Error as u32;
            s.error_code = error_code::INTERNAL;
            s.message = cut;
        }
        if let Some((code, message)) = a.failure() {
            s.state = State::Error as u32;
            s.error_code = code;
            s.message = message;
        }
        s
    }

    /// Stop: ends the capture (the port keeps its window, state stopped); an acquisition
    /// that had ended on an error is moved out of the error state. The reply's `message`
    /// says what was done.
    fn stop(&mut self) -> Reply {
        let cancelled = self.cancel_open("by a Stop").map(|d| format!("cancelled the Acquire of {d:?}; "));
        let cancelled = cancelled.unwrap_or_default();
        let Some(a) = self.current.as_mut() else {
            return Reply::Stopped {
                message: format!("{cancelled}nothing to stop: no acquisition since the broker started"),
            };
        };
        let before = a.port.info().ok().and_then(|i| i.state);
        a.stop(STOP_TIMEOUT);
        let last = a.port.info().map(|i| i.last_frame_index).unwrap_or(0);
        let msg = match a.clear_error() {
            Some(err) => format!("cleared the error state (it was: {err}); state stopped, last frame {last}"),
            None if before == Some(State::Stopped) => format!("already stopped at frame {last}"),
            None => format!("stopped at frame {last}"),
        };
        let msg = format!("{cancelled}{msg}");
        tracing::info!(device = %a.device, "{msg}");
        Reply::Stopped { message: msg }
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

    /// Stops everything (on SIGTERM / SIGINT), within [`SHUTDOWN_STOP_TIMEOUT`]: a pending
    /// Acquire is cancelled, threads stuck in a device are left behind.
    pub fn shutdown(&mut self) {
        self.cancel_open("because the broker is shutting down");
        if let Some(a) = self.current.as_mut() {
            a.stop(SHUTDOWN_STOP_TIMEOUT);
        }
    }
}

/// Why the acquisition's port file is no longer whole (cut under the broker), if it is not:
/// one fstat, so that Status reports a cut even before the capture's next publish trips on it.
fn port_cut(a: &Acquisition) -> Option<String> {
    let len = a.port.file().metadata().ok()?.len();
    (len < a.port.size()).then(|| {
        format!(
            "the port file {} shrank to {len} bytes under the broker (it needs {}): something cut it; \
             Acquire again to make a new port",
            a.port.path().display(),
            a.port.size()
        )
    })
}

/// Whether `peer` may control a broker running as `own_uid` with allowed group `group`.
pub fn peer_allowed(peer: &os::Peer, own_uid: u32, group: Option<u32>) -> bool {
    peer.uid == own_uid || peer.uid == 0 || group.is_some_and(|g| peer.gid == g || peer.groups.contains(&g))
}

/// The running daemon's name: the instance lock (`bassclient::instance`, the same as
/// `bass-bridge mirror` takes), its socket removed at exit.
struct Files {
    inst: Instance,
    socket: PathBuf,
    socket_name: String,
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
fn take_instance(cfg: &Config) -> anyhow::Result<Files> {
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
    let socket_name = inst.socket_name();
    Ok(Files { inst, socket, socket_name })
}

/// Runs the broker until SIGTERM / SIGINT.
pub fn run(cfg: Config) -> anyhow::Result<()> {
    // Catch the termination signals before any thread exists (a wake-up socket the loop polls).
    let signals = os::catch_termination_signals().context("setting up the signal handling")?;
    let files = take_instance(&cfg)?;
    let mode = if cfg.group.is_some() { 0o660 } else { 0o600 };
    let listener =
        os::listen_seqpacket_at(files.inst.dir(), &files.socket_name, &files.socket, mode, cfg.group)
            .with_context(|| format!("listening on {}", files.socket.display()))?;
    tracing::info!(name = %cfg.name, socket = %files.socket.display(), pid = std::process::id(), "bassd ready");
    let own_uid = os::euid();
    let mut broker = Broker::new(cfg.clone());
    if let Some(r) = &cfg.acquire {
        if let Some(Reply::Error { message, .. }) = broker.acquire(r, own_uid, None) {
            tracing::error!("start-up Acquire failed: {message}");
        }
    }
    let mut clients: Vec<Conn> = Vec::new();
    let mut acceptor = Acceptor::new();
    let idle_ns = u64::try_from(cfg.idle_timeout.as_nanos()).unwrap_or(u64::MAX).max(1);
    loop {
        let listening = monotonic_ns() >= acceptor.paused_until_ns;
        // A negative descriptor is ignored by poll: while backing off, the listener is not watched.
        let lfd = if listening { listener.as_raw_fd() } else { -1 };
        // A connection parked on a pending Acquire is not read (its reply comes first).
        let parked = broker.parked_conn();
        let mut fds =
            vec![os::pollin(lfd), os::pollin(signals.as_raw_fd()), os::pollin(broker.open_wake_fd())];
        fds.extend(
            clients.iter().map(|c| os::pollin(if Some(c.id) == parked { -1 } else { c.fd.as_raw_fd() })),
        );
        os::poll(&mut fds, Some(TICK)).context("poll")?;
        broker.tick();
        broker.poll_open();
        if fds[1].revents != 0 {
            if let Some(sig) = os::read_signal(&signals) {
                tracing::info!(signal = sig, "terminating: stopping the capture");
                broker.shutdown();
                drop(files);
                return Ok(());
            }
        }
        // Client requests, then drop closed and idle connections (indices from the back).
        let now = monotonic_ns();
        let mut closed = Vec::new();
        for (i, c) in clients.iter_mut().enumerate() {
            if Some(c.id) == parked {
                // Waiting for its reply is not idleness.
                c.last_ns = now;
                continue;
            }
            let rev = fds[3 + i].revents;
            if rev == 0 {
                if now.saturating_sub(c.last_ns) >= idle_ns {
                    tracing::debug!(
                        pid = c.pid,
                        "closing a control connection idle for {:?}",
                        cfg.idle_timeout
                    );
                    close_idle(&mut broker, c);
                    closed.push(i);
                }
                continue;
            }
            c.last_ns = now;
            if !serve_one(&mut broker, c) {
                closed.push(i);
            }
        }
        for i in closed.into_iter().rev() {
            clients.swap_remove(i);
        }
        if fds[0].revents != 0 {
            acceptor.accept_all(listener.as_fd(), &mut clients, own_uid, cfg.group);
        }
    }
}

/// One open control connection.
struct Conn {
    /// Unique in this process (a pending Acquire names the connection it answers).
    id: u64,
    fd: OwnedFd,
    /// Peer process (for the logs).
    pid: i32,
    /// CLOCK_MONOTONIC (ns) of the accept or of the last request.
    last_ns: u64,
}

impl Conn {
    fn new(fd: OwnedFd, pid: i32) -> Conn {
        static NEXT_ID: AtomicU64 = AtomicU64::new(1);
        Conn { id: NEXT_ID.fetch_add(1, Ordering::Relaxed), fd, pid, last_ns: monotonic_ns() }
    }
}

/// Accepts control connections, and keeps the broker alive when descriptors run out.
///
/// A spare descriptor is held in reserve: when `accept` fails with EMFILE/ENFILE, the
/// spare is given up to accept the waiting connection and refuse it with a message (so the
/// client learns why instead of hanging), then taken again. If even that fails, the
/// listener is not polled for [`ACCEPT_BACKOFF`]; the condition is logged at most once per
/// 10 s with the number of refusals, and accepting resumes by itself once descriptors free up.
struct Acceptor {
    spare: Option<OwnedFd>,
    paused_until_ns: u64,
    out_of_fds: bool,
    refused_since_log: u64,
    last_log_ns: u64,
}

impl Acceptor {
    fn new() -> Acceptor {
        Acceptor {
            spare: os::spare_fd().ok(),
            paused_until_ns: 0,
            out_of_fds: false,
            refused_since_log: 0,
            last_log_ns: 0,
        }
    }

    fn accept_all(
        &mut self,
        listener: BorrowedFd<'_>,
        clients: &mut Vec<Conn>,
        own_uid: u32,
        group: Option<u32>,
    ) {
        if self.spare.is_none() {
            // Lost while descriptors were short: take it again as soon as one is free.
            self.spare = os::spare_fd().ok();
        }
        loop {
            match os::accept(listener) {
                Ok(Some(c)) => {
                    if self.out_of_fds && self.spare.is_some() {
                        self.out_of_fds = false;
                        tracing::info!(
                            refused = self.refused_since_log,
                            "control connections are accepted again (file descriptors freed up)"
                        );
                        self.refused_since_log = 0;
                    }
                    admit(c, clients, own_uid, group);
                }
                Ok(None) => return,
                Err(e) if os::is_out_of_fds(&e) => {
                    self.on_out_of_fds(listener, &e);
                    return;
                }
                Err(e) => {
                    // ECONNABORTED, EPROTO and the like concern one connection: go on later.
                    tracing::debug!("accept: {e}");
                    self.paused_until_ns = monotonic_ns() + ACCEPT_BACKOFF.as_nanos() as u64;
                    return;
                }
            }
        }
    }

    fn on_out_of_fds(&mut self, listener: BorrowedFd<'_>, e: &std::io::Error) {
        let now = monotonic_ns();
        self.out_of_fds = true;
        // Refuse what waits, one connection per spare descriptor round.
        let mut refused_now = 0;
        while refused_now < 64 {
            let Some(spare) = self.spare.take() else { break };
            drop(spare);
            let accepted = os::accept(listener);
            let got_one = matches!(accepted, Ok(Some(_)));
            if let Ok(Some(c)) = &accepted {
                let m = Reply::error(
                    ErrorKind::Internal,
                    "the broker is out of file descriptors; try again later",
                );
                let _ = control::send_reply(c.as_fd(), &m);
                os::drain(c.as_fd());
                refused_now += 1;
            }
            drop(accepted);
            self.spare = os::spare_fd().ok();
            if !got_one || self.spare.is_none() {
                break;
            }
        }
        self.refused_since_log += refused_now.max(1);
        // Still out of descriptors (no spare to give up): stop watching the listener a while.
        if self.spare.is_none() || refused_now == 0 {
            self.paused_until_ns = now + ACCEPT_BACKOFF.as_nanos() as u64;
        }
        if self.last_log_ns == 0 || now.saturating_sub(self.last_log_ns) >= EMFILE_LOG_EVERY_NS {
            self.last_log_ns = now;
            tracing::warn!(
                refused = self.refused_since_log,
                "accept: {e}: out of file descriptors; refusing new control connections until some \
                 close (capture goes on; idle connections close after the idle timeout)"
            );
            self.refused_since_log = 0;
        }
    }
}

/// Checks a new connection's peer and the connection limits; keeps it or refuses it with a reply.
fn admit(c: OwnedFd, clients: &mut Vec<Conn>, own_uid: u32, group: Option<u32>) {
    let fd = c.as_fd();
    let _ = os::set_send_timeout(fd, Duration::from_secs(1));
    let peer = match os::peer_credentials(fd) {
        Ok(p) if peer_allowed(&p, own_uid, group) => Some(p),
        Ok(p) => {
            tracing::warn!(pid = p.pid, uid = p.uid, "refused a control connection (not our user or group)");
            None
        }
        Err(e) => {
            tracing::warn!("refused a control connection: SO_PEERCRED: {e}");
            None
        }
    };
    let refuse = |kind, text: &str| {
        let _ = control::send_reply(c.as_fd(), &Reply::error(kind, text));
        os::drain(fd);
    };
    let Some(peer) = peer else {
        refuse(ErrorKind::Permission, "permission denied: not the broker's user or group");
        return;
    };
    let privileged = peer.uid == own_uid || peer.uid == 0;
    let limit = if privileged { MAX_CLIENTS } else { MAX_CLIENTS - RESERVED_CLIENTS };
    if clients.len() >= limit {
        tracing::warn!(
            pid = peer.pid,
            uid = peer.uid,
            open = clients.len(),
            "refused a control connection: too many"
        );
        refuse(
            ErrorKind::Internal,
            &format!(
                "too many control connections ({} open; {RESERVED_CLIENTS} of {MAX_CLIENTS} are kept for the \
                 broker's own user and root)",
                clients.len()
            ),
        );
        return;
    }
    clients.push(Conn::new(c, peer.pid));
}

/// The last step on a connection closed for idleness (the caller drops it afterwards).
///
/// A request may have arrived since poll returned. Reading is shut first: a request sent from
/// then on fails at the client (EPIPE; the library then reconnects), and one that arrived
/// before is still queued and is answered.
fn close_idle(broker: &mut Broker, c: &Conn) {
    let _ = rustix::net::shutdown(&c.fd, rustix::net::Shutdown::Read);
    if request_pending(&c.fd) {
        serve_one(broker, c);
    }
}

/// Whether a datagram waits on connection `c` (without taking it).
fn request_pending(c: &OwnedFd) -> bool {
    let mut probe = [0u8; 1];
    let flags = rustix::net::RecvFlags::PEEK | rustix::net::RecvFlags::DONTWAIT;
    matches!(rustix::net::recv(c, &mut probe[..], flags), Ok((_, n)) if n > 0)
}

/// Reads one request from `conn` and answers it; false when the connection is finished. An
/// Acquire is answered once its device is open (the connection is parked until then).
///
/// A request in the version-1 text form is answered in that form (`code=version`), the one
/// reply a version-1 client can read; any other version gets a version-2 `error` naming both.
fn serve_one(broker: &mut Broker, conn: &Conn) -> bool {
    let c = &conn.fd;
    let bytes = match control::recv_datagram(c.as_fd()) {
        Ok(None) => return false,
        Ok(Some(b)) => b,
        Err(e) => {
            let reply = Reply::error(ErrorKind::Protocol, &e.to_string());
            return control::send_reply(c.as_fd(), &reply).is_ok();
        }
    };
    let reply = match control::wire::decode_request(&bytes) {
        Ok(Request::OpenPort) => return crate::handoff::serve(c.as_fd(), broker.current.as_ref()),
        Ok(r) => {
            let uid = os::peer_credentials(c.as_fd()).map_or(u32::MAX, |p| p.uid);
            let reply_to = match (&r, c.try_clone()) {
                (Request::Acquire(_), Ok(fd)) => Some(opening::Parked { id: conn.id, fd }),
                (Request::Acquire(_), Err(e)) => {
                    let reply =
                        Reply::error(ErrorKind::Internal, &format!("cannot keep the connection: {e}"));
                    return control::send_reply(c.as_fd(), &reply).is_ok();
                }
                _ => None,
            };
            match broker.handle_as(r, uid, reply_to) {
                Some(reply) => reply,
                None => return true,
            }
        }
        Err(WireError::Version { found }) => {
            let text = format!(
                "this broker speaks {}, the request is {found}: update the client library",
                control::PROTOCOL
            );
            if control::wire::is_v1_text(&bytes) {
                return control::send_datagram(c.as_fd(), &control::wire::v1_error(&text)).is_ok();
            }
            Reply::error(ErrorKind::Version, &text)
        }
        Err(WireError::Malformed(e)) => Reply::error(ErrorKind::Protocol, &e),
    };
    control::send_reply(c.as_fd(), &reply).is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The race behind "the broker closed the connection without a reply": a request that
    /// arrived after poll reported the connection idle is answered, not dropped with it.
    #[test]
    fn a_request_queued_when_an_idle_connection_closes_is_answered() {
        use rustix::net::{socketpair, AddressFamily, SocketFlags, SocketType};
        let (server, client) =
            socketpair(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None).unwrap();
        control::send_request(client.as_fd(), &Request::Status).unwrap();
        let mut broker = Broker::new(Config::default());
        let conn = Conn::new(server, 0);
        close_idle(&mut broker, &conn);
        drop(conn);
        match control::recv_reply(client.as_fd()) {
            Ok(Some(Reply::Status(s))) => assert_eq!(s.epoch, 0, "a broker with no acquisition"),
            other => panic!("the queued request got {other:?}, not its status reply"),
        }
        // And nothing else: the connection is closed after that reply.
        assert!(matches!(control::recv_reply(client.as_fd()), Ok(None)), "the connection stays closed");
    }

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
