//! Where ports and control sockets live, which names are valid, and whose files a client
//! trusts.
//!
//! Runtime directory (docs/broker.md, "Runtime directory"):
//! - `$BASS_RUNTIME_DIR` if set (tests, several private brokers);
//! - else a broker run as root uses [`SYSTEM_RUNTIME_DIR`] (`/run/bass`, created 0755 and
//!   owned by root, so nobody else can plant or squat files there);
//! - else a per-user broker uses [`USER_RUNTIME_DIR`] (`/dev/shm`).
//!
//! A client looks for broker `name` in `/run/bass` first (a system broker), then in `/dev/shm`
//! (its own per-user broker), so a name squatted in the world-writable `/dev/shm` cannot
//! shadow the system broker. Whatever it finds must belong to an expected owner
//! ([`expected_owner_ok`]).

use std::path::PathBuf;

use crate::error::{Error, Result};

/// Environment variable overriding the runtime directory of port files and control
/// sockets (default `/dev/shm`).
pub const RUNTIME_DIR_ENV: &str = "BASS_RUNTIME_DIR";
/// The system broker's runtime directory (brokers run as root).
pub const SYSTEM_RUNTIME_DIR: &str = "/run/bass";
/// The per-user brokers' runtime directory.
pub const USER_RUNTIME_DIR: &str = "/dev/shm";
/// Environment variable naming one more uid whose broker a client trusts (besides root and
/// the client's own uid).
pub const BROKER_UID_ENV: &str = "BASS_BROKER_UID";
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

fn env_runtime_dir() -> Option<PathBuf> {
    std::env::var_os(RUNTIME_DIR_ENV).filter(|d| !d.is_empty()).map(PathBuf::from)
}

/// The runtime directory of a broker run by this process: `$BASS_RUNTIME_DIR`, else
/// `/run/bass` for root, else `/dev/shm`.
pub fn runtime_dir() -> PathBuf {
    env_runtime_dir().unwrap_or_else(|| {
        PathBuf::from(if rustix::process::geteuid().is_root() {
            SYSTEM_RUNTIME_DIR
        } else {
            USER_RUNTIME_DIR
        })
    })
}

/// Where a client finds broker `name`: `$BASS_RUNTIME_DIR`, else `/run/bass` if the system
/// broker of that name is there (its socket or port exists) or the client is root, else
/// `/dev/shm`.
pub fn lookup_dir(name: &str) -> PathBuf {
    if let Some(d) = env_runtime_dir() {
        return d;
    }
    let sys = PathBuf::from(SYSTEM_RUNTIME_DIR);
    let has = |ext: &str| std::fs::symlink_metadata(sys.join(format!("bass-{name}.{ext}"))).is_ok();
    if rustix::process::geteuid().is_root() || has("sock") || has("port") {
        sys
    } else {
        PathBuf::from(USER_RUNTIME_DIR)
    }
}

/// Whether a client trusts a broker, port or socket owned by `uid` (see
/// [`expected_port_owners`], the one definition of whom a client trusts).
pub fn expected_owner_ok(uid: u32) -> bool {
    expected_port_owners().is_ok_and(|owners| owners.contains(&uid))
}

/// Path of the port file of `name`.
pub fn port_path(name: &str) -> Result<PathBuf> {
    check_name(name)?;
    Ok(lookup_dir(name).join(format!("bass-{name}.port")))
}

/// Path of the control socket of broker `name`.
pub fn socket_path(name: &str) -> Result<PathBuf> {
    check_name(name)?;
    Ok(lookup_dir(name).join(format!("bass-{name}.sock")))
}

/// The uids a client accepts as the owner of a port it opens by name or of a broker's
/// control socket: root, the client's own effective uid, `$BASS_BROKER_UID` when set, and
/// the owner of the runtime directory when nobody else can write that directory (only its
/// owner and root can have put a file there, e.g. a `/run/bass` of a broker's own user).
pub fn expected_port_owners() -> Result<Vec<u32>> {
    let own = rustix::process::geteuid().as_raw();
    let mut owners = vec![0, own];
    match std::env::var(BROKER_UID_ENV) {
        Ok(v) if !v.trim().is_empty() => {
            let uid: u32 = v.trim().parse().map_err(|_| {
                Error::InvalidArgument(format!("{BROKER_UID_ENV}={v:?} (expected a numeric uid)"))
            })?;
            owners.push(uid);
        }
        _ => {}
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

/// The name of user `uid` in /etc/passwd, escaped for messages.
pub(crate) fn user_name(uid: u32) -> Option<String> {
    let text = std::fs::read_to_string("/etc/passwd").ok()?;
    text.lines().find_map(|l| {
        let mut f = l.split(':');
        let name = f.next()?;
        let id: u32 = f.nth(1)?.parse().ok()?;
        // Debug formatting escapes anything odd a passwd entry might hold.
        (id == uid).then(|| name.escape_debug().to_string())
    })
}

/// `uid N (name)` for messages; the name comes from /etc/passwd when it is there.
pub fn describe_uid(uid: u32) -> String {
    match user_name(uid) {
        Some(n) => format!("uid {uid} ({n})"),
        None => format!("uid {uid}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn root_and_the_own_user_are_trusted_others_only_when_named() {
        assert!(expected_owner_ok(0));
        assert!(expected_owner_ok(rustix::process::geteuid().as_raw()));
        let named = std::env::var(BROKER_UID_ENV).ok();
        if named.as_deref() != Some("4000000001") {
            assert!(!expected_owner_ok(4_000_000_001));
        }
    }
}
