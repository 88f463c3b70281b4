//! Who is on the other end of a connected Unix socket (SO_PEERCRED through libc: rustix's
//! `socket_peercred` refuses a peer outside this pid namespace, which bass accepts with pid 0).

use std::io;
use std::os::fd::BorrowedFd;

/// Credentials of the peer of a connected Unix socket (SO_PEERCRED).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PeerCred {
    /// Process id in this process's pid namespace; 0 when the peer is not visible in it
    /// (it lives in a pid namespace beside or above ours, e.g. a broker outside a container).
    pub pid: u32,
    /// Effective user id.
    pub uid: u32,
    /// Effective group id.
    pub gid: u32,
}

/// SO_PEERCRED of a connected Unix socket. A peer outside this pid namespace has pid 0
/// (rustix's `socket_peercred` refuses such a peer, so the call is made here).
pub fn peer_credentials(fd: BorrowedFd<'_>) -> io::Result<PeerCred> {
    use std::os::fd::AsRawFd;
    let mut cred = libc::ucred { pid: 0, uid: 0, gid: 0 };
    let mut len = std::mem::size_of::<libc::ucred>() as libc::socklen_t;
    // SAFETY: `cred` is a valid, writable ucred of `len` bytes and `fd` an open descriptor
    // borrowed for the call; the kernel writes at most `len` bytes and reports the length.
    let r = unsafe {
        libc::getsockopt(
            fd.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_PEERCRED,
            (&raw mut cred).cast(),
            &mut len,
        )
    };
    if r != 0 {
        return Err(io::Error::last_os_error());
    }
    if len as usize != std::mem::size_of::<libc::ucred>() {
        return Err(io::Error::new(io::ErrorKind::InvalidData, format!("SO_PEERCRED returned {len} bytes")));
    }
    Ok(PeerCred { pid: u32::try_from(cred.pid).unwrap_or(0), uid: cred.uid, gid: cred.gid })
}
