//! The control plane: the broker's versioned request/reply protocol and its client.
//!
//! One Unix-domain `SOCK_SEQPACKET` socket per broker (`paths::socket_path(name)`); each
//! datagram is one whole message. A message is UTF-8 text: a first line
//! `bass-control/<major> <verb>`, then `key=value` lines. Values escape `\`, newline and
//! tab as `\\`, `\n`, `\t`, so a value is always one line. Unknown keys are ignored
//! (additions within a major version); another major is refused with `code=version`.
//! See docs/control-protocol.md for the full layout and an example.
//!
//! ```text
//!  client                          bassd
//!    | bass-control/1 acquire        |
//!    | device=sim:sine ...     ----> |  validate, stop old, open device, new port
//!    | <---- bass-control/1 ok       |
//!    |       epoch=7 port=/dev/shm/bass-default.port
//! ```
//!
//! This module is the one definition of the protocol: the broker (`broker/`) encodes and
//! decodes with these same types.

use std::os::fd::{AsRawFd, BorrowedFd, FromRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::error::{Error, Result};
use crate::format::State;
use crate::paths;

/// Major version of the control protocol.
pub const PROTOCOL_MAJOR: u32 = 1;
/// Largest message (bytes) either side sends or accepts.
pub const MAX_MESSAGE: usize = 64 * 1024;
/// Default time a client waits for a reply (an Acquire opens and configures a device).
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(15);
/// The seed's default device.
pub const DEFAULT_DEVICE: &str = "hw:1,0";
/// The seed's default sample rate (Hz).
pub const DEFAULT_SAMPLE_RATE: u32 = 44100;
/// The seed's default nFramesPerChunk.
pub const DEFAULT_FRAMES_PER_CHUNK: u32 = 2205;
/// The seed's default nChunksOnPort.
pub const DEFAULT_CHUNKS_ON_PORT: u32 = 20;
/// Default number of channels (binaural).
pub const DEFAULT_CHANNELS: u32 = 2;

const MAGIC_PREFIX: &str = "bass-control/";

/// One protocol message: a verb and ordered `key=value` fields.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Message {
    /// Protocol major version of the message.
    pub major: u32,
    /// Request verb (`acquire`, `stop`, `status`, `list-devices`) or reply verb (`ok`, `error`).
    pub verb: String,
    /// Fields in order; a key may repeat (e.g. `device` in a device list).
    pub fields: Vec<(String, String)>,
}

fn escape(v: &str, out: &mut String) {
    for ch in v.chars() {
        match ch {
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            '\r' => out.push_str("\\r"),
            c => out.push(c),
        }
    }
}

fn unescape(v: &str) -> Result<String> {
    let mut out = String::with_capacity(v.len());
    let mut it = v.chars();
    while let Some(c) = it.next() {
        if c != '\\' {
            out.push(c);
            continue;
        }
        match it.next() {
            Some('\\') => out.push('\\'),
            Some('n') => out.push('\n'),
            Some('t') => out.push('\t'),
            Some('r') => out.push('\r'),
            other => {
                return Err(Error::Protocol(format!("bad escape \\{} in value {v:?}", other.unwrap_or(' '))))
            }
        }
    }
    Ok(out)
}

impl Message {
    /// A message of the current major version.
    pub fn new(verb: &str) -> Message {
        Message { major: PROTOCOL_MAJOR, verb: verb.to_owned(), fields: Vec::new() }
    }

    /// Appends a field.
    pub fn with(mut self, key: &str, value: impl ToString) -> Message {
        self.push(key, value);
        self
    }

    /// Appends a field.
    pub fn push(&mut self, key: &str, value: impl ToString) {
        self.fields.push((key.to_owned(), value.to_string()));
    }

    /// First value of `key`.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.fields.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
    }

    /// All values of `key`, in order.
    pub fn get_all<'a>(&'a self, key: &'a str) -> impl Iterator<Item = &'a str> + 'a {
        self.fields.iter().filter(move |(k, _)| k == key).map(|(_, v)| v.as_str())
    }

    /// Value of `key` parsed as a number; `default` when absent.
    pub fn get_num<T: std::str::FromStr>(&self, key: &str, default: Option<T>) -> Result<T> {
        match self.get(key) {
            Some(v) => {
                v.trim().parse().map_err(|_| Error::Protocol(format!("{key}={v:?} is not a valid number")))
            }
            None => {
                default.ok_or_else(|| Error::Protocol(format!("missing field {key:?} in {:?}", self.verb)))
            }
        }
    }

    /// The wire form.
    pub fn encode(&self) -> Vec<u8> {
        let mut s = format!("{MAGIC_PREFIX}{} {}\n", self.major, self.verb);
        for (k, v) in &self.fields {
            s.push_str(k);
            s.push('=');
            escape(v, &mut s);
            s.push('\n');
        }
        s.into_bytes()
    }

    /// Parses the wire form. The major version is returned as found (the caller decides).
    pub fn decode(bytes: &[u8]) -> Result<Message> {
        let text = std::str::from_utf8(bytes).map_err(|_| Error::Protocol("message is not UTF-8".into()))?;
        let mut lines = text.lines();
        let first = lines.next().unwrap_or("");
        let rest = first.strip_prefix(MAGIC_PREFIX).ok_or_else(|| {
            Error::Protocol(format!("first line {first:?} does not start with {MAGIC_PREFIX:?}"))
        })?;
        let (major, verb) = rest.split_once(' ').unwrap_or((rest, ""));
        let major: u32 = major
            .parse()
            .map_err(|_| Error::Protocol(format!("bad protocol version {major:?} in {first:?}")))?;
        if verb.is_empty() || verb.contains(char::is_whitespace) {
            return Err(Error::Protocol(format!("bad verb in first line {first:?}")));
        }
        let mut fields = Vec::new();
        for line in lines.filter(|l| !l.is_empty()) {
            let (k, v) = line
                .split_once('=')
                .ok_or_else(|| Error::Protocol(format!("line {line:?} is not key=value")))?;
            fields.push((k.to_owned(), unescape(v)?));
        }
        Ok(Message { major, verb: verb.to_owned(), fields })
    }

    /// An `error` reply.
    pub fn error(code: ErrorKind, message: &str) -> Message {
        Message::new("error").with("code", code.as_str()).with("message", message)
    }
}

/// Why the broker refused a request (`code=` of an `error` reply).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// A parameter is out of range or malformed; nothing was changed.
    InvalidArgument,
    /// The device could not be opened or configured; nothing was changed (the message says
    /// what was kept).
    Device,
    /// The peer is not allowed to control this broker.
    Permission,
    /// Another major protocol version.
    Version,
    /// A malformed message or an unknown verb.
    Protocol,
    /// Anything else (e.g. the port file could not be created).
    Internal,
}

impl ErrorKind {
    /// Wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorKind::InvalidArgument => "invalid-argument",
            ErrorKind::Device => "device",
            ErrorKind::Permission => "permission",
            ErrorKind::Version => "version",
            ErrorKind::Protocol => "protocol",
            ErrorKind::Internal => "internal",
        }
    }
}

/// Sample format preference of an Acquire (the port always carries left-justified S32).
pub const FORMATS: [&str; 5] = ["S32_LE", "S24_LE", "S24_3LE", "FLOAT_LE", "S16_LE"];

/// Parameters of an Acquire.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AcquireRequest {
    /// ALSA PCM name or `sim:...`.
    pub device: String,
    /// Sample rate in Hz.
    pub sample_rate: u32,
    /// nFramesPerChunk.
    pub frames_per_chunk: u32,
    /// nChunksOnPort.
    pub chunks_on_port: u32,
    /// Channels.
    pub channels: u32,
    /// Force one device sample format (one of [`FORMATS`]); `None` = the broker's choice.
    pub format: Option<String>,
}

impl Default for AcquireRequest {
    fn default() -> Self {
        AcquireRequest {
            device: DEFAULT_DEVICE.into(),
            sample_rate: DEFAULT_SAMPLE_RATE,
            frames_per_chunk: DEFAULT_FRAMES_PER_CHUNK,
            chunks_on_port: DEFAULT_CHUNKS_ON_PORT,
            channels: DEFAULT_CHANNELS,
            format: None,
        }
    }
}

/// A request to the broker.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Request {
    /// List capture devices.
    ListDevices,
    /// Start (or restart) an acquisition.
    Acquire(AcquireRequest),
    /// Stop the acquisition.
    Stop,
    /// The broker's and the port's state.
    Status,
}

impl Request {
    /// Encodes the request.
    pub fn to_message(&self) -> Message {
        match self {
            Request::ListDevices => Message::new("list-devices"),
            Request::Stop => Message::new("stop"),
            Request::Status => Message::new("status"),
            Request::Acquire(a) => {
                let mut m = Message::new("acquire")
                    .with("device", &a.device)
                    .with("sample_rate", a.sample_rate)
                    .with("frames_per_chunk", a.frames_per_chunk)
                    .with("chunks_on_port", a.chunks_on_port)
                    .with("channels", a.channels);
                if let Some(f) = &a.format {
                    m.push("format", f);
                }
                m
            }
        }
    }

    /// Decodes a request (the major version must already have been checked).
    pub fn from_message(m: &Message) -> Result<Request> {
        Ok(match m.verb.as_str() {
            "list-devices" => Request::ListDevices,
            "stop" => Request::Stop,
            "status" => Request::Status,
            "acquire" => Request::Acquire(AcquireRequest {
                device: m.get("device").unwrap_or(DEFAULT_DEVICE).to_owned(),
                sample_rate: m.get_num("sample_rate", Some(DEFAULT_SAMPLE_RATE))?,
                frames_per_chunk: m.get_num("frames_per_chunk", Some(DEFAULT_FRAMES_PER_CHUNK))?,
                chunks_on_port: m.get_num("chunks_on_port", Some(DEFAULT_CHUNKS_ON_PORT))?,
                channels: m.get_num("channels", Some(DEFAULT_CHANNELS))?,
                format: m.get("format").map(str::to_owned),
            }),
            other => return Err(Error::Protocol(format!("unknown request {other:?}"))),
        })
    }
}

/// Reply to an Acquire.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Acquired {
    /// Epoch of the new acquisition's port.
    pub epoch: u64,
    /// Path of the port file.
    pub port: PathBuf,
    /// Device sample format negotiated (e.g. `S16_LE`; `S32` for simulated devices).
    pub format: String,
}

/// A capture device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceInfo {
    /// Name to pass to Acquire.
    pub name: String,
    /// One-line description.
    pub description: String,
}

/// The broker's and its current port's state.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Status {
    /// Port state ([`State`] as u32; `Idle` before the first Acquire).
    pub state: u32,
    /// `format::error_code` when `state` is Error.
    pub error_code: u32,
    /// Sample rate (Hz).
    pub sample_rate: u32,
    /// nFramesPerChunk.
    pub frames_per_chunk: u32,
    /// nChunksOnPort.
    pub chunks_on_port: u32,
    /// Channels.
    pub channels: u32,
    /// Acquisition epoch (0 before the first Acquire).
    pub epoch: u64,
    /// Newest published frame.
    pub last_frame_index: u64,
    /// Recovered overruns.
    pub xruns: u64,
    /// Zero-filled frames.
    pub gap_frames: u64,
    /// Chunks published.
    pub chunks_published: u64,
    /// Device rate estimate (Hz; 0 = none yet).
    pub rate_estimate_hz: f64,
    /// Device name.
    pub device: String,
    /// Device sample format negotiated.
    pub format: String,
    /// Error (or information) message.
    pub message: String,
    /// Path of the port file ("" before the first Acquire).
    pub port: String,
    /// Broker process id.
    pub broker_pid: u32,
    /// Broker version.
    pub broker_version: String,
}

impl Status {
    /// The port state, decoded.
    pub fn state(&self) -> Option<State> {
        State::from_u32(self.state)
    }

    /// Encodes a status reply.
    pub fn to_message(&self) -> Message {
        Message::new("ok")
            .with("state", self.state)
            .with("error_code", self.error_code)
            .with("sample_rate", self.sample_rate)
            .with("frames_per_chunk", self.frames_per_chunk)
            .with("chunks_on_port", self.chunks_on_port)
            .with("channels", self.channels)
            .with("epoch", self.epoch)
            .with("last_frame_index", self.last_frame_index)
            .with("xruns", self.xruns)
            .with("gap_frames", self.gap_frames)
            .with("chunks_published", self.chunks_published)
            .with("rate_estimate_hz", self.rate_estimate_hz)
            .with("device", &self.device)
            .with("format", &self.format)
            .with("message", &self.message)
            .with("port", &self.port)
            .with("broker_pid", self.broker_pid)
            .with("broker_version", &self.broker_version)
    }

    /// Decodes a status reply.
    pub fn from_message(m: &Message) -> Result<Status> {
        let s = |k: &str| m.get(k).unwrap_or("").to_owned();
        Ok(Status {
            state: m.get_num("state", None)?,
            error_code: m.get_num("error_code", Some(0))?,
            sample_rate: m.get_num("sample_rate", Some(0))?,
            frames_per_chunk: m.get_num("frames_per_chunk", Some(0))?,
            chunks_on_port: m.get_num("chunks_on_port", Some(0))?,
            channels: m.get_num("channels", Some(0))?,
            epoch: m.get_num("epoch", Some(0))?,
            last_frame_index: m.get_num("last_frame_index", Some(0))?,
            xruns: m.get_num("xruns", Some(0))?,
            gap_frames: m.get_num("gap_frames", Some(0))?,
            chunks_published: m.get_num("chunks_published", Some(0))?,
            rate_estimate_hz: m.get_num("rate_estimate_hz", Some(0.0))?,
            device: s("device"),
            format: s("format"),
            message: s("message"),
            port: s("port"),
            broker_pid: m.get_num("broker_pid", Some(0))?,
            broker_version: s("broker_version"),
        })
    }
}

/// Encodes a device list reply: for each device a `device=NAME` field followed by its
/// `description=TEXT` field.
pub fn devices_to_message(devices: &[DeviceInfo]) -> Message {
    let mut m = Message::new("ok");
    for d in devices {
        m.push("device", &d.name);
        m.push("description", &d.description);
    }
    m
}

/// Decodes a device list reply (a `description` belongs to the `device` before it).
pub fn devices_from_message(m: &Message) -> Result<Vec<DeviceInfo>> {
    let mut out: Vec<DeviceInfo> = Vec::new();
    for (k, v) in &m.fields {
        match k.as_str() {
            "device" => out.push(DeviceInfo { name: v.clone(), description: String::new() }),
            "description" => match out.last_mut() {
                Some(d) => d.description = v.clone(),
                None => return Err(Error::Protocol("description before any device".into())),
            },
            _ => {}
        }
    }
    Ok(out)
}

/// A reply decoded into success or the broker's error.
pub fn check_reply(m: Message) -> Result<Message> {
    if m.major != PROTOCOL_MAJOR {
        return Err(Error::Protocol(format!(
            "broker speaks control protocol {}, this library speaks {PROTOCOL_MAJOR}",
            m.major
        )));
    }
    match m.verb.as_str() {
        "ok" => Ok(m),
        "error" => {
            let code = m.get("code").unwrap_or("internal");
            let msg = m.get("message").unwrap_or("(no message)");
            Err(Error::Broker(format!("{msg} [{code}]")))
        }
        other => Err(Error::Protocol(format!("unexpected reply verb {other:?}"))),
    }
}

// ---------------------------------------------------------------------------------------
// The socket edge (SOCK_SEQPACKET): one datagram per message.

/// Sends one message on a connected SEQPACKET socket.
pub fn send_message(fd: BorrowedFd<'_>, m: &Message) -> Result<()> {
    let bytes = m.encode();
    if bytes.len() > MAX_MESSAGE {
        return Err(Error::Protocol(format!("message of {} bytes exceeds {MAX_MESSAGE}", bytes.len())));
    }
    loop {
        // SAFETY: `bytes` is valid for its length; `fd` is an open socket for the call.
        let r = unsafe { libc::send(fd.as_raw_fd(), bytes.as_ptr().cast(), bytes.len(), libc::MSG_NOSIGNAL) };
        if r >= 0 {
            return Ok(());
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(Error::io("send on the control socket", e));
        }
    }
}

/// Receives one message; `Ok(None)` when the peer closed the connection.
pub fn recv_message(fd: BorrowedFd<'_>) -> Result<Option<Message>> {
    let mut buf = vec![0u8; MAX_MESSAGE];
    let mut reset_seen = false;
    loop {
        // SAFETY: `buf` is valid for writes of its length; `fd` is an open socket.
        let r = unsafe { libc::recv(fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len(), libc::MSG_TRUNC) };
        if r == 0 {
            return Ok(None);
        }
        if r > 0 {
            let n = r as usize;
            if n > buf.len() {
                return Err(Error::Protocol(format!("message of {n} bytes exceeds {MAX_MESSAGE}")));
            }
            return Message::decode(&buf[..n]).map(Some);
        }
        let e = std::io::Error::last_os_error();
        match e.kind() {
            std::io::ErrorKind::Interrupted => continue,
            std::io::ErrorKind::WouldBlock => {
                let timed_out = std::io::Error::from(std::io::ErrorKind::TimedOut);
                return Err(Error::io("waiting for the broker's reply", timed_out));
            }
            // A peer that closed with our request unread reports ECONNRESET once, ahead of
            // the reply it may have queued before closing: look again.
            std::io::ErrorKind::ConnectionReset if !reset_seen => reset_seen = true,
            std::io::ErrorKind::ConnectionReset => return Ok(None),
            _ => return Err(Error::io("recv on the control socket", e)),
        }
    }
}

/// Creates a `SOCK_SEQPACKET` Unix socket (close-on-exec).
pub fn seqpacket_socket() -> std::io::Result<OwnedFd> {
    // SAFETY: plain socket(2) call; the result is checked before use.
    let fd = unsafe { libc::socket(libc::AF_UNIX, libc::SOCK_SEQPACKET | libc::SOCK_CLOEXEC, 0) };
    if fd < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: `fd` is a fresh descriptor owned by nobody else.
    Ok(unsafe { OwnedFd::from_raw_fd(fd) })
}

/// A `sockaddr_un` for `path` (at most 107 bytes).
pub fn sockaddr(path: &Path) -> std::io::Result<(libc::sockaddr_un, libc::socklen_t)> {
    use std::os::unix::ffi::OsStrExt;
    let bytes = path.as_os_str().as_bytes();
    // SAFETY: sockaddr_un is plain old data; all-zero is a valid value.
    let mut addr: libc::sockaddr_un = unsafe { std::mem::zeroed() };
    if bytes.len() >= addr.sun_path.len() || bytes.contains(&0) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("socket path {} is longer than {} bytes", path.display(), addr.sun_path.len() - 1),
        ));
    }
    addr.sun_family = libc::AF_UNIX as libc::sa_family_t;
    for (d, s) in addr.sun_path.iter_mut().zip(bytes) {
        *d = *s as libc::c_char;
    }
    let len = std::mem::size_of::<libc::sa_family_t>() + bytes.len() + 1;
    Ok((addr, len as libc::socklen_t))
}

// ---------------------------------------------------------------------------------------

/// Whether a send failed because the broker had closed the connection (EPIPE, ECONNRESET).
fn peer_closed(e: &Error) -> bool {
    matches!(e, Error::Io { source, .. }
        if matches!(source.kind(), std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset))
}

/// A connection to a broker's control socket.
pub struct Client {
    fd: OwnedFd,
    name: String,
    path: std::path::PathBuf,
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
        let fd = seqpacket_socket().map_err(no_broker)?;
        let (addr, len) = sockaddr(path).map_err(no_broker)?;
        loop {
            // SAFETY: `addr` is a valid sockaddr_un of length `len`; `fd` is open.
            let r = unsafe { libc::connect(fd.as_raw_fd(), (&addr as *const libc::sockaddr_un).cast(), len) };
            if r == 0 {
                break;
            }
            let e = std::io::Error::last_os_error();
            if e.kind() != std::io::ErrorKind::Interrupted {
                return Err(no_broker(e));
            }
        }
        // Who serves this socket? The peer credentials are those of the process that called
        // listen(): a socket planted by another user is refused before anything is sent.
        let peer = rustix::net::sockopt::socket_peercred(&fd).map_err(|e| no_broker(e.into()))?;
        let owner = peer.uid.as_raw();
        if !paths::expected_owner_ok(owner) {
            return Err(no_broker(std::io::Error::new(
                std::io::ErrorKind::PermissionDenied,
                format!(
                    "the socket is served by uid {owner} (pid {}), not by root or this user; \
                     set {}={owner} to trust that broker",
                    peer.pid.as_raw_nonzero().get(),
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
        let tv = libc::timeval {
            tv_sec: timeout.as_secs().min(i32::MAX as u64) as libc::time_t,
            tv_usec: timeout.subsec_micros() as libc::suseconds_t,
        };
        // SAFETY: `tv` is a valid timeval for the duration of the call; `fd` is open.
        let r = unsafe {
            libc::setsockopt(
                self.fd.as_raw_fd(),
                libc::SOL_SOCKET,
                libc::SO_RCVTIMEO,
                (&tv as *const libc::timeval).cast(),
                std::mem::size_of::<libc::timeval>() as libc::socklen_t,
            )
        };
        if r != 0 {
            return Err(Error::io("setsockopt(SO_RCVTIMEO)", std::io::Error::last_os_error()));
        }
        Ok(())
    }

    /// Broker name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sends a raw message and returns the raw reply (for tools and tests).
    pub fn call(&mut self, m: &Message) -> Result<Message> {
        if let Err(e) = send_message(self.fd.as_fd_borrowed(), m) {
            // A broker that refuses a connection answers before closing it: read that reply.
            return match recv_message(self.fd.as_fd_borrowed()) {
                Ok(Some(r)) => Ok(r),
                // Closed without a word: the broker closed this connection as idle before the
                // request reached it (it never saw it). Reconnect once and send it again.
                Ok(None) if peer_closed(&e) => {
                    let mut fresh = Client::connect_path(&self.path, &self.name)?;
                    fresh.set_timeout(self.timeout)?;
                    *self = fresh;
                    send_message(self.fd.as_fd_borrowed(), m)?;
                    match recv_message(self.fd.as_fd_borrowed())? {
                        Some(r) => Ok(r),
                        None => {
                            Err(Error::Protocol("the broker closed the connection without a reply".into()))
                        }
                    }
                }
                _ => Err(e),
            };
        }
        match recv_message(self.fd.as_fd_borrowed())? {
            Some(r) => Ok(r),
            None => Err(Error::Protocol("the broker closed the connection without a reply".into())),
        }
    }

    fn request(&mut self, r: &Request) -> Result<Message> {
        let reply = self.call(&r.to_message())?;
        check_reply(reply)
    }

    /// Starts an acquisition (interrupting a running one).
    pub fn acquire(&mut self, req: &AcquireRequest) -> Result<Acquired> {
        let m = self.request(&Request::Acquire(req.clone()))?;
        Ok(Acquired {
            epoch: m.get_num("epoch", None)?,
            port: PathBuf::from(m.get("port").unwrap_or("")),
            format: m.get("format").unwrap_or("").to_owned(),
        })
    }

    /// Stops the acquisition (the port keeps its frames and shows Stopped).
    pub fn stop(&mut self) -> Result<()> {
        self.stop_report().map(drop)
    }

    /// Stops the acquisition and returns what the broker did (its reply's `message`: "stopped
    /// at frame N", "cleared the error state (it was: ...)", "nothing to stop"; empty from a
    /// broker that does not say).
    pub fn stop_report(&mut self) -> Result<String> {
        self.request(&Request::Stop).map(|m| m.get("message").unwrap_or("").to_owned())
    }

    /// The broker's and the port's state.
    pub fn status(&mut self) -> Result<Status> {
        let m = self.request(&Request::Status)?;
        Status::from_message(&m)
    }

    /// The capture devices the broker can open.
    pub fn list_devices(&mut self) -> Result<Vec<DeviceInfo>> {
        let m = self.request(&Request::ListDevices)?;
        devices_from_message(&m)
    }
}

trait AsFdBorrowed {
    fn as_fd_borrowed(&self) -> BorrowedFd<'_>;
}

impl AsFdBorrowed for OwnedFd {
    fn as_fd_borrowed(&self) -> BorrowedFd<'_> {
        use std::os::fd::AsFd;
        self.as_fd()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_round_trip_with_escapes() {
        let m = Message::new("acquire").with("device", "a\\b\nc\td=e").with("sample_rate", 48000);
        let wire = m.encode();
        assert_eq!(
            std::str::from_utf8(&wire).unwrap(),
            "bass-control/1 acquire\ndevice=a\\\\b\\nc\\td=e\nsample_rate=48000\n"
        );
        assert_eq!(Message::decode(&wire).unwrap(), m);
    }

    #[test]
    fn acquire_request_round_trips_and_defaults_to_the_seed() {
        let r = Request::Acquire(AcquireRequest { format: Some("S16_LE".into()), ..Default::default() });
        assert_eq!(Request::from_message(&Message::decode(&r.to_message().encode()).unwrap()).unwrap(), r);
        let bare = Message::decode(b"bass-control/1 acquire\n").unwrap();
        assert_eq!(Request::from_message(&bare).unwrap(), Request::Acquire(AcquireRequest::default()));
    }

    #[test]
    fn device_lists_keep_names_and_descriptions_apart() {
        let d = vec![
            DeviceInfo { name: "hw:CARD=X,DEV=0".into(), description: "Card X\nAnalog\tin".into() },
            DeviceInfo { name: "sim:sine".into(), description: "".into() },
        ];
        let m = Message::decode(&devices_to_message(&d).encode()).unwrap();
        assert_eq!(devices_from_message(&m).unwrap(), d);
    }

    #[test]
    fn malformed_messages_are_named_errors() {
        for bad in [
            &b"hello"[..],
            b"bass-control/x ok\n",
            b"bass-control/1 ok\nnoequals\n",
            b"bass-control/1 ok\nk=\\q\n",
        ] {
            assert!(matches!(Message::decode(bad), Err(Error::Protocol(_))), "{bad:?}");
        }
    }

    #[test]
    fn error_replies_become_broker_errors() {
        let e = check_reply(Message::error(ErrorKind::InvalidArgument, "nFramesPerChunk = 0")).unwrap_err();
        assert!(matches!(&e, Error::Broker(m) if m.contains("nFramesPerChunk = 0")), "{e}");
    }
}
