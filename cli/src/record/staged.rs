//! A recording's sidecar written whole or not at all: staged in a temporary file beside it
//! and renamed into place, by the checkpoints and at the end; and the `recording.end` a
//! checkpoint's sidecar carries.

use std::fs::OpenOptions;
use std::io::{self, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use basskit::sidecar::Sidecar;

/// `recording.end` of a checkpoint.
pub(super) const IN_PROGRESS: &str = "in progress (a checkpoint; the recorder had not ended)";

/// Writes `side` to a temporary file next to the sidecar `path`, to be renamed into place
/// (a reader or a kill sees the old sidecar or the new one, never half of one).
pub(super) fn stage(path: &Path, side: &Sidecar) -> io::Result<PathBuf> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".{}.tmp", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let _ = std::fs::remove_file(&tmp);
    let r = OpenOptions::new()
        .write(true)
        .create_new(true)
        .custom_flags(libc::O_NOFOLLOW)
        .open(&tmp)
        .and_then(|mut f| f.write_all(&serde_json::to_vec_pretty(side)?));
    match r {
        Ok(()) => Ok(tmp),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}
