//! Where ports and control sockets live, and which names are valid.

use std::path::PathBuf;

use crate::error::{Error, Result};

/// Environment variable overriding the runtime directory of port files and control
/// sockets (default `/dev/shm`).
pub const RUNTIME_DIR_ENV: &str = "BASS_RUNTIME_DIR";
/// The default broker (and port) name.
pub const DEFAULT_NAME: &str = "default";

/// Checks a broker/port name: 1 to 64 characters of `[A-Za-z0-9._-]`, not starting with '.'.
pub fn check_name(name: &str) -> Result<()> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && !name.starts_with('.')
        && name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'.' || b == b'_' || b == b'-');
    if ok {
        Ok(())
    } else {
        Err(Error::InvalidArgument(format!(
            "port name {name:?} (use 1 to 64 characters of A-Z a-z 0-9 . _ -, not starting with '.')"
        )))
    }
}

/// The runtime directory: `$BASS_RUNTIME_DIR`, else `/dev/shm`.
pub fn runtime_dir() -> PathBuf {
    std::env::var_os(RUNTIME_DIR_ENV)
        .filter(|d| !d.is_empty())
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/dev/shm"))
}

/// Path of the port file of `name`.
pub fn port_path(name: &str) -> Result<PathBuf> {
    check_name(name)?;
    Ok(runtime_dir().join(format!("bass-{name}.port")))
}

/// Path of the control socket of broker `name`.
pub fn socket_path(name: &str) -> Result<PathBuf> {
    check_name(name)?;
    Ok(runtime_dir().join(format!("bass-{name}.sock")))
}

/// Environment variable naming the uid a reader expects to own the ports it opens by name
/// (a number; default: root or the reader's own uid).
pub const BROKER_UID_ENV: &str = "BASS_BROKER_UID";

/// The uids a reader accepts as the owner of a port it opens by name: `$BASS_BROKER_UID`
/// (plus root) when set, else root and the reader's own effective uid — and, either way, the
/// owner of the runtime directory when nobody else can write that directory (only its owner
/// and root can have put a file there, e.g. a `/run/bass` of a broker's own user).
pub fn expected_port_owners() -> Result<Vec<u32>> {
    let own = rustix::process::geteuid().as_raw();
    let mut owners = vec![0];
    match std::env::var(BROKER_UID_ENV) {
        Ok(v) if !v.trim().is_empty() => {
            let uid: u32 = v.trim().parse().map_err(|_| {
                Error::InvalidArgument(format!("{BROKER_UID_ENV}={v:?} (expected a numeric uid)"))
            })?;
            owners.push(uid);
        }
        _ => owners.push(own),
    }
    if let Ok(st) = rustix::fs::stat(runtime_dir()) {
        if st.st_mode & 0o022 == 0 {
            owners.push(st.st_uid);
        }
    }
    owners.sort_unstable();
    owners.dedup();
    Ok(owners)
}

/// `uid N (name)` for messages; the name comes from /etc/passwd when it is there.
pub fn describe_uid(uid: u32) -> String {
    let name = std::fs::read_to_string("/etc/passwd").ok().and_then(|t| {
        t.lines().find_map(|l| {
            let mut f = l.split(':');
            let name = f.next()?;
            let id: u32 = f.nth(1)?.parse().ok()?;
            (id == uid).then(|| name.to_owned())
        })
    });
    match name {
        // Debug formatting escapes anything odd a passwd entry might hold.
        Some(n) => format!("uid {uid} ({})", n.escape_debug()),
        None => format!("uid {uid}"),
    }
}
