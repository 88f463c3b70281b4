//! One request on one connection: read, decode, answer (an Acquire's answer waits for its
//! device, see [`super::opening`]).

use std::os::fd::{AsFd, OwnedFd};

use bassport::control::{self, ErrorKind, Reply, Request, WireError};

use super::accept::Conn;
use super::{opening, Broker};
use crate::os;

/// The last step on a connection closed for idleness (the caller drops it afterwards).
///
/// A request may have arrived since poll returned. Reading is shut first: a request sent from
/// then on fails at the client (EPIPE; the library then reconnects), and one that arrived
/// before is still queued and is answered.
pub(super) fn close_idle(broker: &mut Broker, c: &Conn) {
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
pub(super) fn serve_one(broker: &mut Broker, conn: &Conn) -> bool {
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
    use crate::config::Config;

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
}
