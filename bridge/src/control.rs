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
use std::path::Path;
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

/// `mirror`: the replica's control socket; every request goes to `key` on Zenoh. Runs in its
/// own threads until `stop` is set; removes the socket file then.
pub fn spawn_forwarder(
    session: &zenoh::Session,
    key: String,
    socket: &Path,
    stop: Arc<AtomicBool>,
) -> Result<()> {
    let _ = std::fs::remove_file(socket);
    let listener = seqpacket()?;
    rustix::net::bind(&listener, &SocketAddrUnix::new(socket)?)
        .with_context(|| format!("bind the replica's control socket {}", socket.display()))?;
    rustix::net::listen(&listener, 16)?;
    let session = session.clone();
    let path = socket.to_owned();
    std::thread::Builder::new().name("control-accept".into()).spawn(move || {
        // A short receive timeout on the listener lets the loop see `stop`.
        let _ = rustix::net::sockopt::set_socket_timeout(
            &listener,
            rustix::net::sockopt::Timeout::Recv,
            Some(Duration::from_millis(200)),
        );
        while !stop.load(Ordering::Relaxed) {
            let Ok(conn) = rustix::net::accept_with(&listener, SocketFlags::CLOEXEC) else { continue };
            let (session, key) = (session.clone(), key.clone());
            let _ = std::thread::Builder::new().name("control-conn".into()).spawn(move || {
                while let Ok(Some(request)) = recv(&conn) {
                    let reply = forward(&session, &key, request);
                    if send(&conn, &reply).is_err() {
                        break;
                    }
                }
            });
        }
        let _ = std::fs::remove_file(&path);
    })?;
    Ok(())
}

fn forward(session: &zenoh::Session, key: &str, request: Vec<u8>) -> Vec<u8> {
    let replies = match session.get(key).payload(request).timeout(REQUEST_TIMEOUT).wait() {
        Ok(r) => r,
        Err(e) => return error_reply(ErrorKind::Internal, &format!("bass-bridge mirror: {e}")),
    };
    match replies.recv() {
        Ok(reply) => match reply.result() {
            Ok(sample) => sample.payload().to_bytes().into_owned(),
            Err(e) => error_reply(ErrorKind::Internal, &format!("bass-bridge: {}", e.payload().try_to_string().unwrap_or_default())),
        },
        Err(_) => error_reply(
            ErrorKind::Permission,
            "remote control is not enabled on the source (bass-bridge serve --allow-control), or the source is unreachable",
        ),
    }
}
