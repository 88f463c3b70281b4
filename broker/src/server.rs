//! The broker's control loop: the control socket, the requests (ListDevices, Acquire, Stop,
//! Status), the stall watchdog and the signals. By role: the instance lock in
//! server/instance.rs, accepting connections and the peer checks in server/accept.rs, one
//! request on one connection in server/dispatch.rs, the configuration in [`crate::config`].
//!
//! One thread runs everything here with `poll` over the listening socket, the signals' wake-up and
//! the client connections; the capture runs on its own thread (see [`crate::capture`]). The
//! Acquire path (checks, refusals, pin budget, device open, the port switch) is in server/acquire.rs;
//! the device open runs on a worker thread bounded by `--open-timeout-ms` (server/opening.rs),
//! so no device can stop this loop from answering, nor from ending on SIGTERM.

use std::os::fd::{AsFd, AsRawFd};
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use bassport::control::{Reply, Request, Status};
use bassport::format::{error_code, State};
use bassport::sys::monotonic_ns;

use crate::capture::Acquisition;
use crate::device;
use crate::os;
use crate::pins::Ledger;
use crate::supervise::Supervisor;

mod accept;
mod acquire;
mod dispatch;
mod instance;
mod opening;
mod resume;
mod startup;

pub use crate::config::{Config, DEFAULT_IDLE_TIMEOUT, DEFAULT_MAX_PORT_BYTES};
pub use accept::{peer_allowed, MAX_CLIENTS, RESERVED_CLIENTS};
use accept::{Acceptor, Conn};
use dispatch::{close_idle, serve_one};
use instance::take_instance;

pub use opening::{DEFAULT_OPEN_TIMEOUT, MAX_STUCK_OPENS};

/// How long a Stop waits for the capture thread before leaving it behind (a healthy one
/// stops within a poll slice; one stuck in a device never does). The control loop waits in
/// it, so it also bounds how late a SIGTERM arriving meanwhile is handled: 500 + 400 ms < 1 s.
const STOP_TIMEOUT: Duration = Duration::from_millis(500);
/// The same on SIGTERM: bassd ends within 1 s in every state (a thread stuck in a device is
/// left behind; the process exits).
const SHUTDOWN_STOP_TIMEOUT: Duration = Duration::from_millis(400);
/// The control loop's tick while a device open or the configured acquisition's start is
/// pending (their time-outs and retries are checked at every tick).
const TICK: Duration = Duration::from_millis(25);
/// The control loop's longest sleep otherwise: it wakes sooner when something is due (a
/// stall, a watchdog ping or STATUS, an idle connection's close, a prune, the end of an
/// accept back-off), and at least this often to store the heartbeat, which keeps it under
/// the 100 ms within which readers take a heartbeat for a live writer without looking its
/// process up. 12.5 wakes a second instead of 40 at a 25 ms tick: on a VM whose idle is HLT
/// only, a wake-up costs ~25 µs of CPU (docs/performance.md, part 7).
const IDLE_TICK_NS: u64 = 80_000_000;
/// The shortest sleep of the control loop (a due time already past is handled at the next
/// wake-up; this keeps the loop from spinning on one).
const MIN_SLEEP_NS: u64 = 1_000_000;
/// A gap between two watchdog ticks longer than this means the broker was frozen.
const FROZEN_NS: u64 = 200_000_000;
// A frozen broker is told from a long sleep by the gap: at least twice the longest sleep.
const _: () = assert!(FROZEN_NS >= 2 * IDLE_TICK_NS);
/// How often superseded ports are checked for remaining readers.
const PRUNE_NS: u64 = 1_000_000_000;
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
    /// The service manager (systemd), if bassd runs under one.
    sup: Supervisor,
    /// The epoch of a port a predecessor left in the fd store that this broker did not
    /// resume, or the last one a predecessor recorded in the instance lock: the next
    /// acquisition's epoch passes it.
    handed_epoch: Option<u64>,
    /// The configured acquisition (`--acquire`) while it has not started ([`startup`]).
    startup: Option<startup::Startup>,
    /// Why the last device open of an Acquire without a client (start-up, retry) failed.
    last_open_failure: Option<String>,
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
            sup: Supervisor::none(),
            handed_epoch: None,
            startup: None,
            last_open_failure: None,
        }
    }

    /// Answers one request of a client running as `peer_uid`. An Acquire is answered later
    /// (None) once its device open is under way: the reply goes to `reply_to` (None: the
    /// start-up Acquire, whose outcome is logged).
    fn handle_as(&mut self, req: Request, peer_uid: u32, reply_to: Option<opening::Parked>) -> Option<Reply> {
        Some(match req {
            Request::ListDevices => Reply::Devices { devices: device::list() },
            Request::Status => Reply::Status(self.status()),
            Request::Stop => {
                self.forget_configured();
                self.stop()
            }
            Request::Acquire(r) => {
                self.forget_configured();
                return self.acquire(&r, peer_uid, reply_to);
            }
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
        self.configured_status(&mut s, monotonic_ns());
        if let Some(op) = &self.opening {
            // An Acquire waits for its device: say so, and what the port does meanwhile.
            let now = monotonic_ns();
            let port = match self.current.as_ref().map(|a| a.port.info()) {
                None => "no port yet".to_owned(),
                Some(_) => {
                    format!("until it opens, the port (epoch {}) is {}", s.epoch, State::name_of(s.state))
                }
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
        s.devices = a.devices(s.xruns, s.gap_frames);
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
        // A broker restarted after a Stop starts afresh.
        self.sup.forget();
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
            a.heartbeat();
            if late {
                a.rebase_watchdog(now);
            } else {
                a.check_stall(now);
            }
        }
        let healthy = self.current.as_ref().map_or(true, Acquisition::healthy);
        if self.sup.active() {
            let line = self.sup.status_due(now).then(|| resume::status_line(&self.status()));
            self.sup.tick(now, healthy, line);
        }
    }

    /// How long the control loop may sleep from `now` until something of the broker's own is
    /// due ([`TICK`] while an open or the configured start is pending).
    fn sleep_ns(&self, now: u64) -> u64 {
        if self.opening.is_some() || self.startup.is_some() {
            return TICK.as_nanos() as u64;
        }
        let mut due = now.saturating_add(IDLE_TICK_NS);
        if let Some(d) = self.current.as_ref().and_then(Acquisition::stall_due_ns) {
            due = due.min(d);
        }
        if !self.pins.is_empty() {
            due = due.min(self.last_prune_ns.saturating_add(PRUNE_NS + 1));
        }
        let healthy = self.current.as_ref().map_or(true, Acquisition::healthy);
        if let Some(d) = self.sup.next_due_ns(healthy) {
            due = due.min(d);
        }
        due.saturating_sub(now).max(MIN_SLEEP_NS)
    }

    /// Stops everything (on SIGTERM / SIGINT), within [`SHUTDOWN_STOP_TIMEOUT`]: a pending
    /// Acquire is cancelled, threads stuck in a device are left behind.
    pub fn shutdown(&mut self) {
        self.sup.stopping();
        self.cancel_open("because the broker is shutting down");
        if let Some(a) = self.current.as_mut() {
            if self.sup.holds_port() && a.running() {
                // The service manager keeps the port: its successor takes it back.
                tracing::info!("leaving the port capturing for the restarted broker (fd store)");
                a.leave_to_successor(SHUTDOWN_STOP_TIMEOUT);
            } else {
                a.stop(SHUTDOWN_STOP_TIMEOUT);
            }
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

/// Runs the broker until SIGTERM / SIGINT.
pub fn run(cfg: Config) -> anyhow::Result<()> {
    // Catch the termination signals before any thread exists (a wake-up socket the loop polls).
    let signals = os::catch_termination_signals().context("setting up the signal handling")?;
    let mut files = take_instance(&cfg)?;
    let mode = if cfg.group.is_some() { 0o660 } else { 0o600 };
    let listener =
        os::listen_seqpacket_at(files.inst.dir(), &files.socket_name, &files.socket, mode, cfg.group)
            .with_context(|| format!("listening on {}", files.socket.display()))?;
    tracing::info!(name = %cfg.name, socket = %files.socket.display(), pid = std::process::id(), "bassd ready");
    let own_uid = os::euid();
    let mut broker = Broker::new(cfg.clone());
    // A memfd port leaves no file whose epoch the next one could continue: the lock says it.
    broker.handed_epoch = files.inst.previous_epoch;
    broker.sup = Supervisor::from_env(cfg.restart_grace_ms);
    let resumed = match broker.sup.take_handed(&cfg.name) {
        Some(handed) => broker.take_back(handed),
        None => false,
    };
    if let (false, Some(r)) = (resumed, &cfg.acquire) {
        broker.start_configured(r);
    }
    broker.sup.ready(&resume::status_line(&broker.status()));
    let mut clients: Vec<Conn> = Vec::new();
    let mut recorded_epoch = None;
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
        let now = monotonic_ns();
        let mut sleep = broker.sleep_ns(now);
        if !listening {
            sleep = sleep.min(acceptor.paused_until_ns.saturating_sub(now).max(MIN_SLEEP_NS));
        }
        for c in clients.iter().filter(|c| Some(c.id) != parked) {
            let idle_end = c.last_ns.saturating_add(idle_ns);
            sleep = sleep.min(idle_end.saturating_sub(now).max(MIN_SLEEP_NS));
        }
        os::poll(&mut fds, Some(Duration::from_nanos(sleep))).context("poll")?;
        broker.tick();
        broker.poll_open();
        broker.tick_configured(monotonic_ns());
        if let Some(e) = broker.current.as_ref().map(|a| a.port.epoch()) {
            if Some(e) != recorded_epoch {
                files.inst.record_epoch(e);
                recorded_epoch = Some(e);
            }
        }
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
