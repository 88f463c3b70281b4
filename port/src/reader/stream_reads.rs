//! The reads of the callback stream.

use super::Port;
use crate::error::Result;
use crate::format::Header;

/// Reads for the callback stream ([`crate::stream`]), which keeps its own wait loop so that
/// its steady path allocates nothing (a device error's message is copied into the stream's
/// own buffer instead of a `String`).
impl Port {
    /// The header, for the stream's atomic loads (futex word, state, error code, message).
    pub(crate) fn stream_header(&self) -> &Header {
        self.header()
    }

    /// The size and SIGBUS checks of every call (no system call on a guarded or sealed port).
    pub(crate) fn stream_check(&self) -> Result<()> {
        self.check_size()?;
        self.check_intact()
    }
}
