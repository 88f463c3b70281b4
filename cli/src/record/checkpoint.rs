//! Checkpoints of the header and the sidecar while recording (what a SIGKILL leaves).

use std::fs::OpenOptions;
use std::io::{self, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::wav;
use basskit::sidecar::Sidecar;

use super::recording::{Out, Recording};

/// How often the header and the sidecar are brought up to date at least (see [`Checkpoints`]).
const CHECKPOINT_EVERY: Duration = Duration::from_secs(1);
/// A checkpoint may take at most this share of the time between two (1 %).
const CHECKPOINT_SHARE: u32 = 100;
/// `recording.end` of a checkpoint.
pub(super) const IN_PROGRESS: &str = "in progress (a checkpoint; the recorder had not ended)";

/// The checkpoints: every [`CHECKPOINT_EVERY`], or less often when the last one took more
/// than 1 / [`CHECKPOINT_SHARE`] of that (a long sidecar). An MCAP recording writes its
/// records and the facts they amount to ([`super::mcap_out`]). The recorder flushes the WAV and
/// takes a snapshot of the sidecar; a thread writes the sidecar to a temporary file, patches
/// the header sizes to the snapshot's frames, and renames the sidecar into place, so the
/// reading never waits for a long sidecar.
pub(super) struct Checkpoints {
    pub(super) last: Instant,
    pub(super) every: Duration,
    pub(super) running: Option<std::thread::JoinHandle<io::Result<Duration>>>,
}

impl Checkpoints {
    pub(super) fn new() -> Checkpoints {
        Checkpoints { last: Instant::now(), every: CHECKPOINT_EVERY, running: None }
    }

    /// Collects a finished checkpoint and starts the next one when it is due.
    pub(super) fn poll(&mut self, rec: &mut Recording) -> io::Result<()> {
        if self.running.as_ref().is_some_and(|h| h.is_finished()) {
            self.wait()?;
        }
        if self.running.is_none() && self.last.elapsed() >= self.every {
            self.last = Instant::now();
            if let Out::Mcap(m) = &rec.out {
                // The messages so far go to the disk, closed by the facts they amount to.
                let side = rec.sidecar(m.frames_in_messages(), IN_PROGRESS, true);
                return match &mut rec.out {
                    Out::Mcap(m) => m.checkpoint(&side),
                    Out::Wav(_) => unreachable!("an MCAP recording"),
                };
            }
            let Out::Wav(w) = &mut rec.out else { unreachable!("a WAV recording") };
            w.flush()?;
            let frames = w.frames();
            let (fb, format, file) = (w.spec().frame_bytes(), w.spec().format, w.file().try_clone()?);
            let side = rec.sidecar(frames, IN_PROGRESS, true);
            let data = side.recording.frames * fb;
            let path = rec.side_path.clone();
            self.running = Some(std::thread::spawn(move || {
                let t0 = Instant::now();
                let tmp = stage(&path, &side)?;
                wav::patch_sizes(&file, format, data)?;
                std::fs::rename(&tmp, &path)?;
                Ok(t0.elapsed())
            }));
        }
        Ok(())
    }

    /// Waits for the checkpoint being written, if any.
    pub(super) fn wait(&mut self) -> io::Result<()> {
        let Some(h) = self.running.take() else { return Ok(()) };
        let took = h.join().map_err(|_| io::Error::other("the checkpoint thread panicked"))??;
        self.every = CHECKPOINT_EVERY.max(took * CHECKPOINT_SHARE);
        Ok(())
    }
}

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
