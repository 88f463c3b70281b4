//! What a client is told when the system refuses it a broker's control socket or port
//! (EACCES/EPERM): the file's mode, owner and group, and the step that lets it in — most often
//! joining the broker's group (`bassd --group bass`, the Debian package's group), which only
//! takes effect at the next login. "Is bassd running?" would be wrong there: it is.

use std::io;
use std::path::Path;

use crate::paths::user_name;

/// What the refused file is and what using it needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A control socket: connecting needs write permission.
    Socket,
    /// A port file: mapping it needs read permission.
    Port,
}

impl Kind {
    fn noun(self) -> &'static str {
        match self {
            Kind::Socket => "socket",
            Kind::Port => "port",
        }
    }

    /// The permission bits (of one rwx triple) the use needs.
    fn needs(self) -> u32 {
        match self {
            Kind::Socket => 0o2,
            Kind::Port => 0o4,
        }
    }
}

/// The facts the advice is built from (gathered by [`refused`], given by tests).
#[derive(Clone, Debug)]
pub struct Facts {
    /// Permission bits of the file (`st_mode & 0o7777`).
    pub mode: u32,
    /// Owner's name (or uid).
    pub owner: String,
    /// Group's name (or gid).
    pub group: String,
    /// Whether this process has the file's group (effective or supplementary).
    pub in_group: bool,
    /// Whether the system's group database lists this user in the file's group (so that a
    /// new login would have it).
    pub listed_member: bool,
}

/// The advice for a refused `kind` at `path`.
pub fn advice(kind: Kind, path: &Path, f: &Facts) -> String {
    let what =
        format!("the {} {} is {:04o} {}:{}", kind.noun(), path.display(), f.mode & 0o7777, f.owner, f.group);
    let group_may = (f.mode >> 3) & kind.needs() != 0;
    match (group_may, f.in_group, f.listed_member) {
        (true, false, false) => format!(
            "permission denied: you are not in the group {g} ({what}): sudo adduser $USER {g}, then log in again",
            g = f.group
        ),
        (true, false, true) => format!(
            "permission denied: this login session is not in the group {g} yet ({what}): log in again \
             (or start a shell with newgrp {g})",
            g = f.group
        ),
        (false, ..) => format!(
            "permission denied: {what}, for its owner only: run this as {}, or have the broker \
             started with bassd --group GROUP for the readers' group",
            if f.owner == "root" { "root".to_owned() } else { format!("{} (or root)", f.owner) }
        ),
        (true, true, _) => format!(
            "permission denied although you are in the group {} ({what}): the directory {} may \
             not be searchable for you",
            f.group,
            path.parent().unwrap_or(Path::new("/")).display()
        ),
    }
}

/// `os` (an error opening or connecting to `path`) explained when it is a refusal of access;
/// any other error, or a file that cannot be examined, is returned unchanged.
pub fn refused(kind: Kind, path: &Path, os: io::Error) -> io::Error {
    if os.kind() != io::ErrorKind::PermissionDenied {
        return os;
    }
    let Ok(st) = rustix::fs::stat(path) else { return os };
    let gid = st.st_gid;
    let in_group = rustix::process::getegid().as_raw() == gid
        || rustix::process::getgroups().is_ok_and(|g| g.iter().any(|x| x.as_raw() == gid));
    let (group, members) = group_entry(gid).unwrap_or_else(|| (gid.to_string(), Vec::new()));
    let me = rustix::process::geteuid().as_raw();
    let my_name = user_name(me);
    let listed_member = my_name.as_ref().is_some_and(|n| members.contains(n)) || primary_gid(me) == Some(gid);
    let facts = Facts {
        mode: st.st_mode & 0o7777,
        owner: user_name(st.st_uid).unwrap_or_else(|| st.st_uid.to_string()),
        group,
        in_group,
        listed_member,
    };
    io::Error::new(io::ErrorKind::PermissionDenied, advice(kind, path, &facts))
}

/// The name and listed members of group `gid` in /etc/group.
fn group_entry(gid: u32) -> Option<(String, Vec<String>)> {
    let text = std::fs::read_to_string("/etc/group").ok()?;
    text.lines().find_map(|l| {
        let mut f = l.split(':');
        let name = f.next()?;
        let id: u32 = f.nth(1)?.parse().ok()?;
        let members = f.next().unwrap_or("").split(',').filter(|m| !m.is_empty()).map(str::to_owned);
        (id == gid).then(|| (name.escape_debug().to_string(), members.collect()))
    })
}

/// The primary group of user `uid` in /etc/passwd.
fn primary_gid(uid: u32) -> Option<u32> {
    let text = std::fs::read_to_string("/etc/passwd").ok()?;
    text.lines().find_map(|l| {
        let mut f = l.split(':').skip(2);
        let id: u32 = f.next()?.parse().ok()?;
        let gid: u32 = f.next()?.parse().ok()?;
        (id == uid).then_some(gid)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn facts(mode: u32, in_group: bool, listed_member: bool) -> Facts {
        Facts { mode, owner: "root".into(), group: "bass".into(), in_group, listed_member }
    }

    #[test]
    fn a_user_outside_the_group_is_told_to_join_it_and_log_in_again() {
        let p = Path::new("/run/bass/bass-default.sock");
        assert_eq!(
            advice(Kind::Socket, p, &facts(0o660, false, false)),
            "permission denied: you are not in the group bass (the socket /run/bass/bass-default.sock \
             is 0660 root:bass): sudo adduser $USER bass, then log in again"
        );
        let port = advice(Kind::Port, Path::new("/run/bass/bass-default.port"), &facts(0o640, false, false));
        assert!(
            port.contains("not in the group bass (the port /run/bass/bass-default.port is 0640 root:bass)")
        );
        assert!(port.contains("sudo adduser $USER bass, then log in again"), "{port}");
    }

    #[test]
    fn a_member_whose_session_predates_the_membership_is_told_to_log_in_again() {
        let m = advice(Kind::Socket, Path::new("/run/bass/s.sock"), &facts(0o660, false, true));
        assert!(m.contains("not in the group bass yet") && m.contains("log in again"), "{m}");
        assert!(!m.contains("adduser"), "{m}");
    }

    #[test]
    fn a_file_of_the_owner_only_names_the_owner_and_bassd_group() {
        // A port is readable by the group at 0640, a socket is not usable by it at 0640.
        let m = advice(Kind::Socket, Path::new("/dev/shm/bass-default.sock"), &facts(0o640, false, false));
        assert!(m.contains("is 0640 root:bass, for its owner only") && m.contains("bassd --group"), "{m}");
        let m = advice(Kind::Port, Path::new("/x/bass-a.port"), &facts(0o600, true, true));
        assert!(m.contains("for its owner only: run this as root"), "{m}");
    }

    #[test]
    fn other_errors_are_left_as_they_are() {
        let e = refused(Kind::Socket, Path::new("/nonexistent/x.sock"), io::ErrorKind::NotFound.into());
        assert_eq!(e.kind(), io::ErrorKind::NotFound);
        let e = io::Error::from_raw_os_error(libc::EACCES);
        let kept = refused(Kind::Port, Path::new("/nonexistent/x.port"), e);
        assert_eq!(kept.raw_os_error(), Some(libc::EACCES), "a file that cannot be examined");
    }
}
