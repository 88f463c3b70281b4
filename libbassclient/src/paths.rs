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
