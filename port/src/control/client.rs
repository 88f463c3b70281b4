//! The client of a broker's control socket: connect (checking who serves the socket), one
//! request and one reply at a time, a transparent reconnect when the broker closed an idle
//! connection.

use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::messages::{AcquireRequest, Acquired, DeviceInfo, ErrorKind, Reply, Request, Status};
use super::socket;
use crate::error::{Error, Result};
use crate::paths;

/// Default time a client waits for a reply (an Acquire opens and configures a device).
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(15);

/// Whether a send failed because the broker had closed the connection (EPIPE, ECONNRESET).
fn peer_closed(e: &Error) -> bool {
    matches!(e, Error::Io { source, .. }
        if matches!(source.kind(), std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset))
}

fn closed_without_reply() -> Error {
    Error::Protocol("the broker closed the connection without a reply".into())
}

/// A connection to a broker's control socket.
///
/// Acquire through the broker, then read its port (needs a running `bassd`):
///
/// ```no_run
/// use std::time::Duration;
/// use bassport::control::{AcquireRequest, Client};
/// use bassport::Port;
///
/// let mut broker = Client::connect("default")?;
/// let req = AcquireRequest { device: "sim:pattern".into(), sample_rate: 48000, ..Default::default() };
/// let acquired = broker.acquire(&req)?;
/// let port = Port::open("default")?;
/// assert_eq!(port.epoch(), acquired.epoch);
/// port.wait(4800, Duration::from_secs(5))?;
/// let (mut left, mut right, mut nfr) = (vec![0; 4800], vec![0; 4800], 1);
/// let read = port.get_audio_data(4800, &mut nfr, &mut [&mut left, &mut right])?;
/// println!("{} frames, {} lost; broker state {}", read.frames, read.loss, broker.status()?.state);
/// broker.stop()?;
/// # Ok::<(), bassport::Error>(())
/// ```
///
/// No broker of that name is an error naming it (runs without a broker):
///
/// ```
/// # let dir = std::env::temp_dir().join(format!("bass-doc-client-{}", std::process::id()));
/// # std::fs::create_dir_all(&dir).unwrap();
/// # std::env::set_var("BASS_RUNTIME_DIR", &dir);
/// use bassport::{control::Client, Error};
/// let e = Client::connect("nobody-here").err().unwrap();
/// assert!(matches!(e, Error::NoBroker { ref name, .. } if name == "nobody-here"));
/// # std::fs::remove_dir_all(&dir).ok();
/// ```
pub struct Client {
    fd: OwnedFd,
    name: String,
    path: PathBuf,
    timeout: Duration,
}

impl Client {
    /// Connects to broker `name` (`paths::DEFAULT_NAME` for the default broker).
    pub fn connect(name: &str) -> Result<Client> {
        let path = paths::socket_path(name)?;
        Client::connect_path(&path, name)
    }

    /// Connects to the control socket at `path`.
    pub fn connect_path(path: &Path, name: &str) -> Result<Client> {
        let no_broker = |source| Error::NoBroker { name: name.to_owned(), path: path.to_owned(), source };
        let fd = socket::connect(path)
            .map_err(|e| no_broker(crate::access::refused(crate::access::Kind::Socket, path, e)))?;
        // Who serves this socket? The peer credentials are those of the process that called
        // listen(): a socket planted by another user is refused before anything is sent.
        let peer = socket::peer_credentials(fd.as_fd()).map_err(no_broker)?;
        let owner = peer.uid;
        if !paths::expected_owner_ok(owner) {
            return Err(no_broker(std::io::Error::new(
                std::io::ErrorKind::PermissionDenied,
                format!(
                    "the socket is served by uid {owner} (pid {}), not by root or this user; \
                     set {}={owner} to trust that broker",
                    peer.pid,
                    paths::BROKER_UID_ENV
                ),
            )));
        }
        let mut c = Client { fd, name: name.to_owned(), path: path.to_owned(), timeout: DEFAULT_TIMEOUT };
        c.set_timeout(DEFAULT_TIMEOUT)?;
        Ok(c)
    }

    /// Sets how long to wait for a reply.
    pub fn set_timeout(&mut self, timeout: Duration) -> Result<()> {
        self.timeout = timeout;
        socket::set_timeouts(self.fd.as_fd(), Some(timeout), None)
            .map_err(|e| Error::io("setsockopt(SO_RCVTIMEO)", e))
    }

    /// Broker name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sends one request and returns the broker's reply as it came, `error` replies
    /// included (for tools and tests).
    pub fn call(&mut self, r: &Request) -> Result<Reply> {
        self.call_raw(&super::wire::encode_request(r))
    }

    /// Sends raw bytes as one datagram and returns the decoded reply (for tests of the
    /// broker's handling of malformed requests).
    pub fn call_raw(&mut self, bytes: &[u8]) -> Result<Reply> {
        if let Err(e) = socket::send_datagram(self.fd.as_fd(), bytes) {
            // A broker that refuses a connection answers before closing it: read that reply.
            return match socket::recv_reply(self.fd.as_fd()) {
                Ok(Some(r)) => Ok(r),
                // Closed without a word: the broker closed this connection as idle before the
                // request reached it (it never saw it). Reconnect once and send it again.
                Ok(None) if peer_closed(&e) => {
                    let mut fresh = Client::connect_path(&self.path, &self.name)?;
                    fresh.set_timeout(self.timeout)?;
                    *self = fresh;
                    socket::send_datagram(self.fd.as_fd(), bytes)?;
                    socket::recv_reply(self.fd.as_fd())?.ok_or_else(closed_without_reply)
                }
                _ => Err(e),
            };
        }
        socket::recv_reply(self.fd.as_fd())?.ok_or_else(closed_without_reply)
    }

    /// Sends `r`; an `error` reply becomes [`Error::Broker`] with the broker's message and kind.
    fn request(&mut self, r: &Request) -> Result<Reply> {
        match self.call(r)? {
            Reply::Error { kind, message } => Err(Error::Broker(format!("{message} [{}]", kind.as_str()))),
            ok => Ok(ok),
        }
    }

    /// Starts an acquisition (interrupting a running one).
    pub fn acquire(&mut self, req: &AcquireRequest) -> Result<Acquired> {
        match self.request(&Request::Acquire(req.clone()))? {
            // A broker that predates followers ignores them: it captured the master alone.
            Reply::Acquired(a) if !req.followers.is_empty() && a.devices == 0 => {
                Err(Error::Protocol(format!(
                    "the broker acquired {:?} but ignored the {} follower device(s): it predates \
                 several-device acquisitions (docs/multi-device.md); upgrade bassd",
                    req.device,
                    req.followers.len()
                )))
            }
            Reply::Acquired(a) => Ok(a),
            other => Err(unexpected("acquire", &other)),
        }
    }

    /// Stops the acquisition (the port keeps its frames and shows Stopped).
    pub fn stop(&mut self) -> Result<()> {
        self.stop_report().map(drop)
    }

    /// Stops the acquisition and returns the broker's account of what was stopped.
    pub fn stop_report(&mut self) -> Result<String> {
        match self.request(&Request::Stop)? {
            Reply::Stopped { message } => Ok(message),
            other => Err(unexpected("stop", &other)),
        }
    }

    /// The broker's and the port's state.
    pub fn status(&mut self) -> Result<Status> {
        match self.request(&Request::Status)? {
            Reply::Status(s) => Ok(s),
            other => Err(unexpected("status", &other)),
        }
    }

    /// The capture devices the broker can open.
    pub fn list_devices(&mut self) -> Result<Vec<DeviceInfo>> {
        match self.request(&Request::ListDevices)? {
            Reply::Devices { devices } => Ok(devices),
            other => Err(unexpected("list-devices", &other)),
        }
    }
}

/// The broker's answer to `open-port`.
#[derive(Debug)]
pub enum OpenedPort {
    /// A sealed memfd port: its read-only descriptor.
    Fd {
        /// Epoch of the port.
        epoch: u64,
        /// The descriptor (close-on-exec).
        fd: OwnedFd,
    },
    /// A file port: open this path.
    File(PathBuf),
}

impl Client {
    /// Asks for the current port (`open-port`): a memfd port's descriptor, or a file port's
    /// path. Any descriptor the reply does not call for is closed.
    pub fn open_port(&mut self) -> Result<OpenedPort> {
        match self.open_port_reply()? {
            (Reply::PortFd(p), Some(fd)) => Ok(OpenedPort::Fd { epoch: p.epoch, fd }),
            (Reply::PortFd(_), None) => {
                Err(Error::Protocol("the broker's port-fd reply came without a descriptor".into()))
            }
            (Reply::PortFile { port }, _) => Ok(OpenedPort::File(port)),
            (Reply::Error { kind, message }, _) => {
                Err(Error::Broker(format!("{message} [{}]", kind.as_str())))
            }
            (other, _) => Err(unexpected("open-port", &other)),
        }
    }

    /// Sends `open-port` and returns the reply as it came, with its descriptor if any.
    fn open_port_reply(&mut self) -> Result<(Reply, Option<OwnedFd>)> {
        let bytes = super::wire::encode_request(&Request::OpenPort);
        if let Err(e) = socket::send_datagram(self.fd.as_fd(), &bytes) {
            // A broker that refuses a connection answers before closing it: read that reply.
            match socket::recv_reply_with_fd(self.fd.as_fd()) {
                Ok(Some(r)) => return Ok(r),
                // Closed as idle before the request reached the broker: once more, anew.
                Ok(None) if peer_closed(&e) => {
                    let mut fresh = Client::connect_path(&self.path, &self.name)?;
                    fresh.set_timeout(self.timeout)?;
                    *self = fresh;
                    socket::send_datagram(self.fd.as_fd(), &bytes)?;
                }
                _ => return Err(e),
            }
        }
        socket::recv_reply_with_fd(self.fd.as_fd())?.ok_or_else(closed_without_reply)
    }
}

/// How long [`crate::Port::open`] waits for a broker's `open-port` reply before it leaves
/// the path's answer (a broker busy opening a device, or stopped, must not hang an opener
/// for the full [`DEFAULT_TIMEOUT`]).
pub const OPEN_PORT_TIMEOUT: Duration = Duration::from_secs(5);

/// For [`crate::Port::open`]: the port of broker `name` through its control socket, if that
/// broker hands out a memfd port. `Ok(None)`: no broker, a file port, or a broker that does
/// not know `open-port` (the caller falls back to the path). A broker that refuses this
/// client's user is [`Error::Broker`].
pub(crate) fn port_from_broker(name: &str) -> Result<Option<crate::Port>> {
    let path = paths::socket_path(name)?;
    if path.symlink_metadata().is_err() {
        return Ok(None);
    }
    let mut c = Client::connect_path(&path, name)?;
    c.set_timeout(OPEN_PORT_TIMEOUT)?;
    match c.open_port_reply()? {
        (Reply::PortFd(_), Some(fd)) => crate::Port::from_fd(fd, name).map(Some),
        (Reply::Error { kind: ErrorKind::Permission, message }, _) => {
            Err(Error::Broker(format!("{message} [{}]", ErrorKind::Permission.as_str())))
        }
        // A file port, an older broker ("unknown request"), no port yet: the path decides.
        _ => Ok(None),
    }
}

/// For a reader of a memfd port whose writer has died: the epoch of the memfd port broker
/// `name` serves now, if it serves one (a successor that did not take the reader's port
/// back: its readers cannot be told through that port, which nobody writes any more). None
/// when no broker answers, it has no port yet, or its port is a file. The descriptor that
/// comes with the answer is closed at once.
pub(crate) fn broker_memfd_epoch(name: &str) -> Option<u64> {
    let path = paths::socket_path(name).ok()?;
    path.symlink_metadata().ok()?;
    let mut c = Client::connect_path(&path, name).ok()?;
    c.set_timeout(SUCCESSOR_QUERY_TIMEOUT).ok()?;
    match c.open_port_reply().ok()? {
        (Reply::PortFd(p), Some(_fd)) => Some(p.epoch),
        _ => None,
    }
}

/// How long [`broker_memfd_epoch`] waits for the broker's answer.
const SUCCESSOR_QUERY_TIMEOUT: Duration = Duration::from_millis(500);

fn unexpected(request: &str, reply: &Reply) -> Error {
    Error::Protocol(format!("the broker answered a {request} request with {reply:?}"))
}
