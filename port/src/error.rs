//! The library's error type; each variant maps to one stable C result code.

use std::path::PathBuf;

/// Errors of the port writer, reader and control client.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An argument is out of range; the message names it and its value.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// No port file with that name.
    #[error("no port {name:?} at {}", path.display())]
    NotFound {
        /// Port name.
        name: String,
        /// Path tried.
        path: PathBuf,
    },
    /// The port exists but its header is not published yet (version 0); retry.
    #[error("port is not initialised yet (format version 0); retry")]
    NotReady,
    /// Not a bass port.
    #[error("not a bass port: magic {found:#018x}")]
    BadMagic {
        /// Magic found.
        found: u64,
    },
    /// A port of another major format version.
    #[error("incompatible port format: major version {found}, this library reads {expected}")]
    Incompatible {
        /// Major version found.
        found: u32,
        /// Major version supported.
        expected: u32,
    },
    /// The header or the shared state is inconsistent.
    #[error("corrupt port: {0}")]
    Corrupt(String),
    /// An operating-system call failed.
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// A wait expired.
    #[error("timed out waiting for frame {frame} (last frame {last})")]
    Timeout {
        /// Frame waited for.
        frame: u64,
        /// Last frame index when the wait gave up.
        last: u64,
    },
    /// The acquisition was stopped.
    #[error("acquisition stopped at frame {last}")]
    Stopped {
        /// Last frame index.
        last: u64,
    },
    /// The acquisition ended on a device error.
    #[error("device error (code {code}): {message}")]
    Device {
        /// `format::error_code`.
        code: u32,
        /// Message from the broker.
        message: String,
    },
    /// A newer acquisition replaced this port; reopen it.
    #[error("a new acquisition replaced this port; reopen it")]
    Restarted,
    /// The writer process is gone.
    #[error("the broker (pid {pid}) that writes this port is gone")]
    WriterGone {
        /// Writer pid.
        pid: u32,
    },
    /// The frame has left the window.
    #[error("frame {frame} has left the window (oldest frame {oldest})")]
    FrameLost {
        /// Frame asked for.
        frame: u64,
        /// Oldest frame on the port.
        oldest: u64,
    },
    /// The frame is not published yet.
    #[error("frame {frame} is not published yet (last frame {last})")]
    FrameNotYet {
        /// Frame asked for.
        frame: u64,
        /// Last frame index.
        last: u64,
    },
    /// A signal interrupted a wait.
    #[error("interrupted by a signal")]
    Interrupted,
    /// The broker refused or failed a request.
    #[error("broker: {0}")]
    Broker(String),
    /// The broker could not be reached.
    #[error("cannot reach broker {name:?} at {}: {source}", path.display())]
    NoBroker {
        /// Broker name.
        name: String,
        /// Socket path.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The broker answered with something this library does not understand.
    #[error("control protocol: {0}")]
    Protocol(String),
    /// A port file opened by name is owned by a user the reader does not trust.
    #[error(
        "{} is owned by {owner}, not by {expected}: another user may have created it in \
         place of the broker's port (set BASS_BROKER_UID to the broker's uid if this is expected)",
        path.display()
    )]
    WrongOwner {
        /// The port file.
        path: PathBuf,
        /// Its owner ("uid 65534 (nobody)").
        owner: String,
        /// Whom the reader expected ("uid 0 (root) or uid 1000 (ann)").
        expected: String,
    },
    /// A port file whose header never became valid: version 0 although nothing has
    /// written it for a while, so no writer is initialising it.
    #[error(
        "{} never became ready: its header is still unwritten (format version 0) {age_ms} ms \
         after the file last changed; no writer is initialising it (a stale or foreign file)",
        path.display()
    )]
    NeverReady {
        /// The port file.
        path: PathBuf,
        /// Milliseconds since the file last changed.
        age_ms: u64,
    },
}

impl Error {
    /// Wraps an OS error with what was being done.
    pub fn io(context: impl Into<String>, source: std::io::Error) -> Error {
        Error::Io { context: context.into(), source }
    }

    /// Whether a broker's socket or port refused this process (EACCES/EPERM, or a socket served
    /// by a user it does not trust): the broker may well run, but this user may not use it.
    pub fn is_access_refused(&self) -> bool {
        matches!(self, Error::NoBroker { source, .. } | Error::Io { source, .. }
            if source.kind() == std::io::ErrorKind::PermissionDenied)
    }
}

/// Shorthand.
pub type Result<T, E = Error> = std::result::Result<T, E>;
