//! Remote control, opt-in: `mirror` answers on the replica's control socket and forwards every
//! request to the source's broker through the `NS/<broker>/control` queryable, which `serve`
//! declares only with `--allow-control`.
//!
//! Requests and replies cross as opaque bytes, one SOCK_SEQPACKET datagram each: the bridge
//! never parses the control protocol, so a change of its encoding needs no change here. The
//! source's broker applies its own checks (peer credentials of the `serve` process, device
//! policy) as for any local client. The only message the bridge makes itself is the error
//! reply when nobody answers, built by the library (`control::Reply::error`, encoded by `control::wire`).

use std::os::fd::{AsFd, OwnedFd};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{anyhow, Context, Result};
use bassclient::control::{wire, ErrorKind, Reply, MAX_MESSAGE};
use rustix::net::{AddressFamily, RecvFlags, SendFlags, SocketAddrUnix, SocketFlags, SocketType};
use zenoh::Wait;

/// How long a forwarded request may take end to end (an Acquire opens a device).
const REQUEST_TIMEOUT: Duration = Duration::from_secs(10);
/// Control requests from mirrors answered at the same time; more are refused as busy (a
/// flood of queries must not become a flood of threads).
const MAX_CONCURRENT_QUERIES: usize = 8;

fn seqpacket() -> std::io::Result<OwnedFd> {
    Ok(rustix::net::socket_with(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None)?)
}

fn send(fd: impl AsFd, bytes: &[u8]) -> std::io::Result<()> {
    loop {
        match rustix::net::send(&fd, bytes, SendFlags::NOSIGNAL) {
            Err(rustix::io::Errno::INTR) => continue,
            r => return r.map(drop).map_err(Into::into),
        }
    }
}

/// One datagram; `None` when the peer closed.
fn recv(fd: impl AsFd) -> std::io::Result<Option<Vec<u8>>> {
    let mut buf = vec![0u8; MAX_MESSAGE];
    loop {
        match rustix::net::recv(&fd, &mut buf[..], RecvFlags::TRUNC) {
            Err(rustix::io::Errno::INTR) => continue,
            Err(rustix::io::Errno::CONNRESET) => return Ok(None),
            Err(e) => return Err(e.into()),
            Ok((_, 0)) => return Ok(None),
            Ok((_, n)) if n > MAX_MESSAGE => {
                return Err(std::io::Error::other(format!(
                    "control message of {n} bytes exceeds {MAX_MESSAGE}"
                )))
            }
            Ok((_, n)) => return Ok(Some(buf[..n].to_vec())),
        }
    }
}

/// Sends `request` to the local broker `name` and returns its reply, as bytes.
fn ask_local_broker(name: &str, request: &[u8]) -> Result<Vec<u8>> {
    let path = bassclient::paths::socket_path(name)?;
    let fd = seqpacket()?;
    rustix::net::connect(&fd, &SocketAddrUnix::new(&path)?)
        .with_context(|| format!("connect to the broker's control socket {}", path.display()))?;
    rustix::net::sockopt::set_socket_timeout(
        &fd,
        rustix::net::sockopt::Timeout::Recv,
        Some(REQUEST_TIMEOUT),
    )?;
    send(&fd, request)?;
    recv(&fd)?.ok_or_else(|| anyhow!("the broker closed the connection without a reply"))
}

fn error_reply(kind: ErrorKind, text: &str) -> Vec<u8> {
    wire::encode_reply(&Reply::error(kind, text))
}

/// `serve --allow-control`: answers control requests from mirrors with the local broker's reply.
/// `hold` delays every request before it goes to the broker (fault injection for the tests;
/// zero otherwise).
pub fn declare_queryable(
    session: &zenoh::Session,
    key: &str,
    broker: &str,
    hold: Duration,
) -> Result<zenoh::query::Queryable<()>> {
    let broker = broker.to_owned();
    let in_flight = Arc::new(AtomicUsize::new(0));
    session
        .declare_queryable(key)
        .callback(move |q| {
            if in_flight.fetch_add(1, Ordering::AcqRel) >= MAX_CONCURRENT_QUERIES {
                in_flight.fetch_sub(1, Ordering::AcqRel);
                let text = format!(
                    "bass-bridge serve: busy ({MAX_CONCURRENT_QUERIES} control requests in progress); try again"
                );
                if let Err(e) = q.reply(q.key_expr().clone(), error_reply(ErrorKind::Internal, &text)).wait() {
                    tracing::debug!("control reply: {e}");
                }
                return;
            }
            // The broker may take a while (an Acquire opens a device): answer from a thread of
            // its own, never from Zenoh's runtime, which also carries the chunks.
            let broker = broker.clone();
            let done = in_flight.clone();
            let spawned = std::thread::Builder::new().name("control-query".into()).spawn(move || {
                let request = q.payload().map(|p| p.to_bytes().into_owned()).unwrap_or_default();
                if !hold.is_zero() {
                    std::thread::sleep(hold);
                }
                let reply = ask_local_broker(&broker, &request).unwrap_or_else(|e| {
                    tracing::warn!("remote control: {e:#}");
                    error_reply(ErrorKind::Internal, &format!("bass-bridge serve: {e:#}"))
                });
                if let Err(e) = q.reply(q.key_expr().clone(), reply).wait() {
                    tracing::debug!("control reply: {e}");
                }
                done.fetch_sub(1, Ordering::AcqRel);
            });
            if let Err(e) = spawned {
                in_flight.fetch_sub(1, Ordering::AcqRel);
                tracing::warn!("remote control: cannot start a thread for a request: {e}");
            }
        })
        .wait()
        .map_err(|e| anyhow!("declare the control queryable: {e}"))
}

/// Most connections to a mirror's control socket open at once (each has a thread while it
/// lives); more are refused with a reply saying so. bassd keeps 128 with 8 reserved for its
/// own user and root; a mirror's socket is reachable by its own user and root only (mode
/// 0600), so one bound serves.
pub const MAX_CONNECTIONS: usize = 16;
/// A connection with no request for this long is closed (bassd: `--idle-timeout-ms`, 30 s).
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(30);

/// The replica's control socket, served by [`spawn_forwarder`]; [`Forwarder::stop`] ends it.
pub struct Forwarder {
    stop: Arc<AtomicBool>,
    accept: Option<std::thread::JoinHandle<()>>,
}

impl Forwarder {
    /// Stops accepting (within 0.2 s); connections in progress end on their own.
    pub fn stop(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.accept.take() {
            let _ = t.join();
        }
    }
}

/// `mirror`: the replica's control socket (`instance`'s, whose name the caller holds: any
/// socket there was left by a process that died and is already gone); every request goes to
/// `key` on Zenoh. At most [`MAX_CONNECTIONS`] connections, each closed after
/// [`IDLE_TIMEOUT`] without a request; peers other than this process's user and root are
/// refused. Runs until `stop` is set; the caller removes the socket file.
pub fn spawn_forwarder(
    session: &zenoh::Session,
    key: String,
    instance: &bassclient::instance::Instance,
    stop: Arc<AtomicBool>,
) -> Result<Forwarder> {
    let socket = instance.socket_path();
    let listener = seqpacket()?;
    rustix::net::bind(&listener, &SocketAddrUnix::new(&socket)?)
        .with_context(|| format!("bind the replica's control socket {}", socket.display()))?;
    // Only its owner (and root) may connect: write permission on the socket file.
    rustix::fs::chmodat(
        instance.dir(),
        instance.socket_name().as_str(),
        rustix::fs::Mode::from_raw_mode(0o600),
        rustix::fs::AtFlags::empty(),
    )
    .with_context(|| format!("chmod {}", socket.display()))?;
    rustix::net::listen(&listener, 64)?;
    let session = session.clone();
    let open = Arc::new(AtomicUsize::new(0));
    let stop_accept = stop.clone();
    let accept = std::thread::Builder::new().name("control-accept".into()).spawn(move || {
        // A short receive timeout on the listener lets the loop see `stop`.
        let _ = rustix::net::sockopt::set_socket_timeout(
            &listener,
            rustix::net::sockopt::Timeout::Recv,
            Some(Duration::from_millis(200)),
        );
        let own = rustix::process::geteuid().as_raw();
        let mut refused_log = 0u64;
        while !stop_accept.load(Ordering::Relaxed) {
            let Ok(conn) = rustix::net::accept_with(&listener, SocketFlags::CLOEXEC) else { continue };
            let _ = rustix::net::sockopt::set_socket_timeout(
                &conn,
                rustix::net::sockopt::Timeout::Send,
                Some(Duration::from_secs(1)),
            );
            let peer_ok =
                bassclient::control::peer_credentials(conn.as_fd()).is_ok_and(|c| c.uid == own || c.uid == 0);
            if !peer_ok {
                let _ = send(
                    &conn,
                    &error_reply(ErrorKind::Permission, "permission denied: not the mirror's user"),
                );
                continue;
            }
            if open.fetch_add(1, Ordering::AcqRel) >= MAX_CONNECTIONS {
                open.fetch_sub(1, Ordering::AcqRel);
                let text = format!(
                    "too many control connections to this mirror ({MAX_CONNECTIONS} open); try again later"
                );
                let _ = send(&conn, &error_reply(ErrorKind::Internal, &text));
                refused_log += 1;
                if refused_log.is_power_of_two() {
                    tracing::warn!(refused = refused_log, "control socket: {text}");
                }
                continue;
            }
            let (session, key, done, stop) =
                (session.clone(), key.clone(), open.clone(), stop_accept.clone());
            let spawned = std::thread::Builder::new().name("control-conn".into()).spawn(move || {
                let _ = rustix::net::sockopt::set_socket_timeout(
                    &conn,
                    rustix::net::sockopt::Timeout::Recv,
                    Some(IDLE_TIMEOUT),
                );
                while !stop.load(Ordering::Relaxed) {
                    let Ok(Some(request)) = recv(&conn) else { break };
                    let reply = forward(&session, &key, request);
                    if send(&conn, &reply).is_err() {
                        break;
                    }
                }
                done.fetch_sub(1, Ordering::AcqRel);
            });
            if spawned.is_err() {
                open.fetch_sub(1, Ordering::AcqRel);
            }
        }
    })?;
    Ok(Forwarder { stop, accept: Some(accept) })
}

/// A reply from the network made safe to print: every string in it escaped when it holds a
/// control character ([`crate::text::escape`]); a reply that is not a JSON object is replaced
/// by an error saying so.
pub fn sanitize_reply(bytes: &[u8]) -> Vec<u8> {
    fn walk(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::String(s) if crate::text::needs_escape(s) => *s = crate::text::escape(s),
            serde_json::Value::Array(a) => a.iter_mut().for_each(walk),
            serde_json::Value::Object(o) => o.values_mut().for_each(walk),
            _ => {}
        }
    }
    match serde_json::from_slice::<serde_json::Value>(bytes) {
        Ok(mut v) if v.is_object() => {
            walk(&mut v);
            serde_json::to_vec(&v).unwrap_or_default()
        }
        _ => error_reply(
            ErrorKind::Protocol,
            &format!(
                "bass-bridge mirror: the source answered with {} bytes that are not a bass control reply",
                bytes.len()
            ),
        ),
    }
}

fn forward(session: &zenoh::Session, key: &str, request: Vec<u8>) -> Vec<u8> {
    let replies = match session.get(key).payload(request).timeout(REQUEST_TIMEOUT).wait() {
        Ok(r) => r,
        Err(e) => {
            return error_reply(
                ErrorKind::Internal,
                &format!("bass-bridge mirror: {}", crate::text::escape(&e.to_string())),
            )
        }
    };
    match replies.recv() {
        Ok(reply) => match reply.result() {
            Ok(sample) => sanitize_reply(&sample.payload().to_bytes()),
            Err(e) => error_reply(
                ErrorKind::Internal,
                &format!("bass-bridge: {}", crate::text::escape_bytes(&e.payload().to_bytes())),
            ),
        },
        Err(_) => error_reply(
            ErrorKind::Permission,
            "remote control is not enabled on the source (bass-bridge serve --allow-control), or the source is unreachable",
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(bytes: &[u8]) -> String {
        match wire::decode_reply(bytes).unwrap() {
            Reply::Error { message, .. } => message,
            other => panic!("not an error reply: {other:?}"),
        }
    }

    #[test]
    fn a_reply_from_the_network_reaches_the_terminal_escaped() {
        let forged = error_reply(ErrorKind::Internal, "\x1b]0;owned\x07\x1b[2J gone");
        assert!(message(&forged).contains('\x1b'), "the forged reply carries ESC");
        let clean = message(&sanitize_reply(&forged));
        assert_eq!(clean, "\\x1b]0;owned\\x07\\x1b[2J gone");
        // A reply without control characters is passed on as it is.
        let plain = error_reply(ErrorKind::Internal, r"C:\path is fine");
        assert_eq!(message(&sanitize_reply(&plain)), r"C:\path is fine");
        // Not a control reply at all: an error saying so.
        assert!(message(&sanitize_reply(b"\x1b[2J")).contains("not a bass control reply"));
    }
}
