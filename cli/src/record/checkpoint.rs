//! Checkpoints of the header and the sidecar while recording (what a SIGKILL leaves).

use std::io;
use std::time::{Duration, Instant};

use crate::wav;

use super::recording::{Out, Recording};
use super::staged::{stage, IN_PROGRESS};

/// How often the header and the sidecar are brought up to date at least (see [`Checkpoints`]).
const CHECKPOINT_EVERY: Duration = Duration::from_secs(1);
/// A checkpoint may take at most this share of the time between two (1 %).
const CHECKPOINT_SHARE: u32 = 100;

/// The checkpoints: every [`CHECKPOINT_EVERY`], or less often when the last one took more
/// than 1 / [`CHECKPOINT_SHARE`] of that (a long sidecar). An MCAP recording writes its
/// records and the facts they amount to ([`super::mcap_out`]); an XDF recording its chunks
/// ([`super::xdf_out`]). The recorder flushes the WAV and
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
            if let Out::Xdf(x) = &mut rec.out {
                // The chunks so far go to the disk, whole.
                return x.checkpoint();
            }
            if let Out::Mcap(m) = &rec.out {
                // The messages so far go to the disk, closed by the facts they amount to.
                let side = rec.sidecar(m.frames_in_messages(), IN_PROGRESS, true);
                return match &mut rec.out {
                    Out::Mcap(m) => m.checkpoint(&side),
                    _ => unreachable!("an MCAP recording"),
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
