//! The control socket's edge: Unix-domain `SOCK_SEQPACKET` sockets (through rustix), one
//! datagram per message, and the typed send/receive of requests and replies over them.

use std::io::{self, IoSlice, IoSliceMut};
use std::mem::MaybeUninit;
use std::os::fd::{BorrowedFd, OwnedFd};
use std::path::Path;

use rustix::io::Errno;
use rustix::net::{
    AddressFamily, RecvAncillaryBuffer, RecvAncillaryMessage, RecvFlags, ReturnFlags, SendAncillaryBuffer,
    SendAncillaryMessage, SendFlags, SocketAddrUnix, SocketFlags, SocketType,
};

use super::messages::{Reply, Request};
use super::wire::{self, WireError, MAX_MESSAGE};
use crate::error::{Error, Result};

/// Creates a `SOCK_SEQPACKET` Unix socket (close-on-exec).
pub fn seqpacket_socket() -> io::Result<OwnedFd> {
    Ok(rustix::net::socket_with(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None)?)
}

/// The socket address of `path`, refused with a readable message when it is too long.
pub fn unix_addr(path: &Path) -> io::Result<SocketAddrUnix> {
    SocketAddrUnix::new(path).map_err(|e| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "socket path {} cannot be a Unix socket address: {e} (at most 107 bytes)",
                path.display()
            ),
        )
    })
}

/// Connects a new SEQPACKET socket to `path`.
pub fn connect(path: &Path) -> io::Result<OwnedFd> {
    let fd = seqpacket_socket()?;
    let addr = unix_addr(path)?;
    loop {
        match rustix::net::connect(&fd, &addr) {
            Ok(()) => return Ok(fd),
            Err(Errno::INTR) => continue,
            Err(e) => return Err(e.into()),
        }
    }
}

pub use crate::sys::peer::{peer_credentials, PeerCred};

/// Sends one datagram on a connected SEQPACKET socket (never raises SIGPIPE).
pub fn send_datagram(fd: BorrowedFd<'_>, bytes: &[u8]) -> Result<()> {
    if bytes.len() > MAX_MESSAGE {
        return Err(Error::Protocol(format!("message of {} bytes exceeds {MAX_MESSAGE}", bytes.len())));
    }
    loop {
        match rustix::net::send(fd, bytes, SendFlags::NOSIGNAL) {
            Ok(_) => return Ok(()),
            Err(Errno::INTR) => continue,
            Err(e) => return Err(Error::io("send on the control socket", e.into())),
        }
    }
}

/// Receives one datagram; `Ok(None)` when the peer closed the connection.
pub fn recv_datagram(fd: BorrowedFd<'_>) -> Result<Option<Vec<u8>>> {
    let mut buf = vec![0u8; MAX_MESSAGE];
    let mut reset_seen = false;
    loop {
        // MSG_TRUNC: the result is the datagram's real length, even if it did not fit.
        match rustix::net::recv(fd, &mut buf[..], RecvFlags::TRUNC) {
            Ok((_, 0)) => return Ok(None),
            Ok((_, n)) if n > MAX_MESSAGE => {
                return Err(Error::Protocol(format!("message of {n} bytes exceeds {MAX_MESSAGE}")))
            }
            Ok((_, n)) => {
                buf.truncate(n);
                return Ok(Some(buf));
            }
            Err(Errno::INTR) => continue,
            Err(Errno::WOULDBLOCK) => {
                let timed_out = io::Error::from(io::ErrorKind::TimedOut);
                return Err(Error::io("waiting for the broker's reply", timed_out));
            }
            // A peer that closed with our request unread reports ECONNRESET once, ahead of
            // the reply it may have queued before closing: look again.
            Err(Errno::CONNRESET) if !reset_seen => reset_seen = true,
            Err(Errno::CONNRESET) => return Ok(None),
            Err(e) => return Err(Error::io("recv on the control socket", e.into())),
        }
    }
}

/// Sends a request.
pub fn send_request(fd: BorrowedFd<'_>, r: &Request) -> Result<()> {
    send_datagram(fd, &wire::encode_request(r))
}

/// Sends a reply.
pub fn send_reply(fd: BorrowedFd<'_>, r: &Reply) -> Result<()> {
    send_datagram(fd, &wire::encode_reply(r))
}

/// Receives a reply; `Ok(None)` when the peer closed the connection. A reply of another
/// protocol version is an [`Error::Protocol`] naming both versions.
pub fn recv_reply(fd: BorrowedFd<'_>) -> Result<Option<Reply>> {
    let Some(bytes) = recv_datagram(fd)? else { return Ok(None) };
    match wire::decode_reply(&bytes) {
        Ok(r) => Ok(Some(r)),
        Err(WireError::Version { found }) => Err(Error::Protocol(format!(
            "the broker speaks {found}, this library speaks {}: update the broker or the library",
            wire::PROTOCOL
        ))),
        Err(WireError::Malformed(e)) => Err(Error::Protocol(format!("malformed reply from the broker: {e}"))),
    }
}

/// Sends a reply with one descriptor attached (SCM_RIGHTS): the answer to `open-port`.
pub fn send_reply_with_fd(fd: BorrowedFd<'_>, r: &Reply, attached: BorrowedFd<'_>) -> Result<()> {
    let bytes = wire::encode_reply(r);
    if bytes.len() > MAX_MESSAGE {
        return Err(Error::Protocol(format!("message of {} bytes exceeds {MAX_MESSAGE}", bytes.len())));
    }
    let fds = [attached];
    let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(1))];
    let mut control = SendAncillaryBuffer::new(&mut space);
    if !control.push(SendAncillaryMessage::ScmRights(&fds)) {
        return Err(Error::Protocol("no room for the descriptor in the control message".into()));
    }
    loop {
        match rustix::net::sendmsg(fd, &[IoSlice::new(&bytes)], &mut control, SendFlags::NOSIGNAL) {
            Ok(_) => return Ok(()),
            Err(Errno::INTR) => continue,
            Err(e) => return Err(Error::io("sendmsg on the control socket", e.into())),
        }
    }
}

/// Most descriptors a reply is received with; any beyond are discarded by the kernel
/// (`MSG_CTRUNC`), and every one received that the reply does not call for is closed.
const MAX_FDS: usize = 4;

/// Receives a reply and the descriptor attached to it, if any: `Ok(None)` when the peer
/// closed the connection. Descriptors arrive close-on-exec (`MSG_CMSG_CLOEXEC`). A reply
/// with more than one descriptor, or with a truncated control message, is refused (and every
/// descriptor it brought is closed).
pub fn recv_reply_with_fd(fd: BorrowedFd<'_>) -> Result<Option<(Reply, Option<OwnedFd>)>> {
    let mut buf = vec![0u8; MAX_MESSAGE];
    let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(MAX_FDS))];
    let mut reset_seen = false;
    let (n, flags, mut fds) = loop {
        let mut control = RecvAncillaryBuffer::new(&mut space);
        let mut iov = [IoSliceMut::new(&mut buf)];
        match rustix::net::recvmsg(fd, &mut iov, &mut control, RecvFlags::CMSG_CLOEXEC | RecvFlags::TRUNC) {
            Ok(m) => {
                let mut fds = Vec::new();
                for msg in control.drain() {
                    if let RecvAncillaryMessage::ScmRights(got) = msg {
                        fds.extend(got);
                    }
                }
                break (m.bytes, m.flags, fds);
            }
            Err(Errno::INTR) => continue,
            Err(Errno::WOULDBLOCK) => {
                let timed_out = io::Error::from(io::ErrorKind::TimedOut);
                return Err(Error::io("waiting for the broker's reply", timed_out));
            }
            Err(Errno::CONNRESET) if !reset_seen => reset_seen = true,
            Err(Errno::CONNRESET) => return Ok(None),
            Err(e) => return Err(Error::io("recvmsg on the control socket", e.into())),
        }
    };
    if n == 0 && fds.is_empty() {
        return Ok(None);
    }
    if n > MAX_MESSAGE {
        return Err(Error::Protocol(format!("message of {n} bytes exceeds {MAX_MESSAGE}")));
    }
    if flags.contains(ReturnFlags::CTRUNC) || fds.len() > 1 {
        return Err(Error::Protocol(format!(
            "the broker's reply came with {}{} descriptors; at most one was expected (all closed)",
            fds.len(),
            if flags.contains(ReturnFlags::CTRUNC) { " or more" } else { "" }
        )));
    }
    let reply = match wire::decode_reply(&buf[..n]) {
        Ok(r) => r,
        Err(WireError::Version { found }) => {
            return Err(Error::Protocol(format!(
                "the broker speaks {found}, this library speaks {}: update the broker or the library",
                wire::PROTOCOL
            )))
        }
        Err(WireError::Malformed(e)) => {
            return Err(Error::Protocol(format!("malformed reply from the broker: {e}")))
        }
    };
    Ok(Some((reply, fds.pop())))
}

/// Sets how long a receive (`SO_RCVTIMEO`) or a send (`SO_SNDTIMEO`) may block.
pub fn set_timeouts(
    fd: BorrowedFd<'_>,
    recv: Option<std::time::Duration>,
    send: Option<std::time::Duration>,
) -> io::Result<()> {
    use rustix::net::sockopt::{set_socket_timeout, Timeout};
    // A zero duration would mean "no timeout" to the kernel: round it up to 1 µs.
    let nonzero = |t: std::time::Duration| Some(t.max(std::time::Duration::from_micros(1)));
    if let Some(t) = recv {
        set_socket_timeout(fd, Timeout::Recv, nonzero(t))?;
    }
    if let Some(t) = send {
        set_socket_timeout(fd, Timeout::Send, nonzero(t))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::fd::AsFd;

    fn pair() -> (OwnedFd, OwnedFd) {
        rustix::net::socketpair(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None)
            .unwrap()
    }

    #[test]
    fn a_version_1_broker_s_reply_is_refused_naming_both_versions() {
        let (client, broker) = pair();
        send_datagram(broker.as_fd(), b"bass-control/1 error\ncode=protocol\nmessage=first line ...\n")
            .unwrap();
        let e = recv_reply(client.as_fd()).unwrap_err();
        let text = e.to_string();
        assert!(matches!(e, Error::Protocol(_)), "{e:?}");
        assert!(text.contains("bass-control/1") && text.contains("bass-control/2"), "{text}");
    }

    #[test]
    fn replies_cross_the_socket_typed_and_a_closed_peer_reads_as_none() {
        let (client, broker) = pair();
        let r = Reply::Stopped { message: "stopped the acquisition of sim:sine".into() };
        send_reply(broker.as_fd(), &r).unwrap();
        assert_eq!(recv_reply(client.as_fd()).unwrap(), Some(r));
        drop(broker);
        assert_eq!(recv_reply(client.as_fd()).unwrap(), None);
    }

    #[test]
    fn a_descriptor_crosses_with_its_reply_and_extra_ones_are_refused() {
        use crate::control::messages::PortFd;
        let (client, broker) = pair();
        let file = crate::memfd::create("socket-test", 4096).unwrap();
        let r = Reply::PortFd(PortFd { epoch: 1, size: 4096 });
        send_reply_with_fd(broker.as_fd(), &r, file.as_fd()).unwrap();
        let (got, fd) = recv_reply_with_fd(client.as_fd()).unwrap().unwrap();
        assert_eq!(got, r);
        let fd = fd.expect("the descriptor");
        assert_eq!(rustix::fs::fstat(&fd).unwrap().st_size, 4096);
        let flags = rustix::io::fcntl_getfd(&fd).unwrap();
        assert!(flags.contains(rustix::io::FdFlags::CLOEXEC), "received close-on-exec");
        // A plain reply reads with no descriptor.
        send_reply(broker.as_fd(), &r).unwrap();
        assert_eq!(recv_reply_with_fd(client.as_fd()).unwrap().unwrap().1.map(|_| ()), None);
        // Two descriptors: refused.
        let bytes = wire::encode_reply(&r);
        let two = [file.as_fd(), file.as_fd()];
        let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(2))];
        let mut control = SendAncillaryBuffer::new(&mut space);
        assert!(control.push(SendAncillaryMessage::ScmRights(&two)));
        rustix::net::sendmsg(&broker, &[IoSlice::new(&bytes)], &mut control, SendFlags::NOSIGNAL).unwrap();
        let e = recv_reply_with_fd(client.as_fd()).unwrap_err();
        assert!(e.to_string().contains("came with 2 descriptors"), "{e}");
        drop(broker);
        assert!(recv_reply_with_fd(client.as_fd()).unwrap().is_none());
    }

    #[test]
    fn oversized_datagrams_are_refused_on_both_sides() {
        let (a, b) = pair();
        let big = vec![b' '; MAX_MESSAGE + 1];
        assert!(matches!(send_datagram(a.as_fd(), &big), Err(Error::Protocol(_))));
        // Sent past the check, it is refused on receipt with its real length.
        rustix::net::send(&a, &big, SendFlags::NOSIGNAL).unwrap();
        let e = recv_datagram(b.as_fd()).unwrap_err();
        assert!(e.to_string().contains(&format!("{} bytes", MAX_MESSAGE + 1)), "{e}");
    }
}
