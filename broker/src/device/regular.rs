//! Opening a recording to replay (a WAV or MCAP file) without ever blocking on what is not a
//! regular file.

use std::fs::File;
use std::path::Path;

/// Opens `path` (a `kind` file: "WAV" or "MCAP", for the messages) for reading if it is a regular file, without ever blocking: a FIFO (or a
/// device node) would block `open` until someone writes to it, and with it the Acquire, every
/// later request and bassd's shutdown. The open is non-blocking (a FIFO opens at once), the
/// type is checked on the open descriptor (no race with a rename), then the descriptor is
/// made blocking again for the reads of a regular file.
pub(super) fn open(path: &Path, kind: &str) -> Result<File, String> {
    use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
    let name = path.display();
    let f = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32)
        .open(path)
        .map_err(|e| format!("sim:file:{name}: cannot read the {kind} file: {e}"))?;
    let t = f.metadata().map_err(|e| format!("sim:file:{name}: {e}"))?.file_type();
    if !t.is_file() {
        let what = if t.is_fifo() {
            "a FIFO"
        } else if t.is_char_device() || t.is_block_device() {
            "a device node"
        } else if t.is_socket() {
            "a socket"
        } else {
            "not a regular file"
        };
        return Err(format!("sim:file:{name} is {what}: give a regular {kind} file"));
    }
    rustix::fs::fcntl_setfl(&f, rustix::fs::OFlags::empty()).map_err(|e| format!("sim:file:{name}: {e}"))?;
    Ok(f)
}
