//! A port handed from one writer process to its successor: the broker restarted by its
//! service manager takes back the port it left in systemd's file descriptor store and goes
//! on publishing the same frames (docs/broker.md, "Restarts that readers ride through").
//!
//! ```text
//!  writer 1: publish .. publish ─ leave_to_successor (or crash) ─┐  port: state kept,
//!                                                                │  heartbeat = last sign
//!  readers: wait ... (writer dead, but within restart_grace_ms: no WriterGone) ...
//!                                                                │
//!  writer 2: Writer::resume(the same descriptor) ─ publish lfi+1 ┘  pid, start time: new;
//!                                                                   epoch, frames: kept
//! ```
//!
//! Nothing of the port changes identity: same epoch, same window, same last frame index;
//! only the writer's pid and start time in the header are the successor's.

use std::fs::File;
use std::path::Path;
use std::sync::atomic::Ordering::{Relaxed, Release};
use std::sync::Arc;

use super::{wake, Backing, Writer};
use crate::error::{Error, Result};
use crate::format::{self, State};
use crate::memfd;
use crate::shm::Mapping;
use crate::sys;
use crate::waker::Waker;

impl Writer {
    /// Takes back the port in `file` (open read-write: the descriptor a predecessor left in
    /// the service manager's store) as its writer. The header is validated like a reader's
    /// (geometry, offsets, size); a superseded port, or one another live process writes, is
    /// refused. The epoch, the window and the last frame index stay; the writer's pid and
    /// start time become this process's; a port left in an error or stopped state is
    /// starting again (its next publish makes it capturing). `path` is the port's path (for
    /// a memfd port, the path a file port of its name would have).
    ///
    /// ```
    /// use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-resume-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// # let path = dir.join("bass-doc.port");
    /// let geometry = Geometry { channels: 1, sample_rate: 8000, frames_per_chunk: 2, chunks_on_port: 4 };
    /// let mut w = Writer::create_at(&path, &PortParams { geometry, device: "doc".into(), group: None })?;
    /// w.set_restart_grace_ms(5_000);
    /// w.publish(Source::Interleaved(&[1, 2]), ChunkMeta::default())?;
    /// let file = std::fs::OpenOptions::new().read(true).write(true).open(&path).unwrap();
    /// w.leave_to_successor(); // the port stays capturing, for the successor
    /// drop(w);
    ///
    /// let mut w2 = Writer::resume(file, &path)?;
    /// assert_eq!((w2.epoch(), w2.last_frame_index()), (1, 2));
    /// w2.publish(Source::Interleaved(&[3, 4]), ChunkMeta::default())?;
    /// let port = Port::open_path(&path)?;
    /// let (mut s, mut nfr) = (vec![0; 4], 1);
    /// port.get_audio_data(4, &mut nfr, &mut [&mut s])?;
    /// assert_eq!(s, vec![1, 2, 3, 4]);
    /// # drop(port);
    /// # w2.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn resume(file: File, path: &Path) -> Result<Writer> {
        let meta = file.metadata().map_err(|e| Error::io("fstat of the port to resume", e))?;
        if !meta.file_type().is_file() {
            return Err(Error::Corrupt(format!(
                "the port to resume ({}) is not a regular file",
                path.display()
            )));
        }
        let sealed = memfd::size_sealed(std::os::fd::AsFd::as_fd(&file));
        let mut mapping = Mapping::new(&file, meta.len(), true)?;
        if !sealed {
            mapping.guard();
        }
        let v = format::validate(mapping.header(), meta.len())?;
        if mapping.broken() {
            return Err(Error::Corrupt(format!("the port to resume ({}) shrank", path.display())));
        }
        let h = mapping.header();
        let state = h.state.load(Relaxed);
        match State::from_u32(state) {
            Some(State::Superseded) => {
                return Err(Error::InvalidArgument(format!(
                    "the port to resume ({}) was superseded by a newer acquisition",
                    path.display()
                )))
            }
            None => return Err(Error::Corrupt(format!("the port to resume has state {state}"))),
            Some(_) => {}
        }
        let pid = h.writer_pid.load(Relaxed);
        if pid != std::process::id() && sys::writer_alive(pid, h.writer_start_time.load(Relaxed)) {
            return Err(Error::InvalidArgument(format!(
                "the port to resume ({}) is still written by live process {pid}",
                path.display()
            )));
        }
        // The start time before the pid: a reader that sees the new pid with the old start
        // time takes the writer for dead, which the restart grace covers.
        h.writer_start_time.store(sys::own_start_time(), Relaxed);
        h.writer_pid_ns.store(sys::own_pid_ns().unwrap_or(0), Relaxed);
        h.writer_pid.store(std::process::id(), Relaxed);
        h.heartbeat_mono_ns.store(sys::monotonic_ns(), Relaxed);
        if matches!(State::from_u32(state), Some(State::Stopped | State::Error)) {
            format::write_text(&h.message, "");
            h.error_code.store(format::error_code::NONE, Relaxed);
            h.state.store(State::Starting as u32, Release);
        }
        wake(h);
        let mapping = Arc::new(mapping);
        let waker = Waker::new(mapping.clone());
        let epoch = mapping.header().epoch.load(Relaxed);
        Ok(Writer {
            mapping,
            waker,
            lead: super::lead::Lead::new(v.geometry.chunk_ns()),
            file,
            backing: if sealed { Backing::Memfd } else { Backing::File },
            path: path.to_owned(),
            geometry: v.geometry,
            layout: v.layout,
            epoch,
            handed_over: false,
        })
    }

    /// Lets readers wait up to `ms` after this writer's last heartbeat for a successor that
    /// takes the port back ([`Writer::resume`]) before they report the writer gone; 0 (the
    /// default) = a dead writer is gone at once.
    pub fn set_restart_grace_ms(&self, ms: u32) {
        self.header().restart_grace_ms.store(ms, Relaxed);
    }

    /// Leaves the port to a successor without ending the acquisition: from here on this
    /// writer publishes nothing more, and neither [`Writer::stop`] nor dropping it changes the
    /// port, which keeps its state (capturing) and frames, with a fresh heartbeat, for a
    /// successor to [`Writer::resume`]. Readers wait for it up to the restart grace
    /// ([`Writer::set_restart_grace_ms`]).
    pub fn leave_to_successor(&mut self) {
        self.heartbeat();
        self.handed_over = true;
    }

    /// Whether this writer left the port to a successor.
    pub fn handed_over(&self) -> bool {
        self.handed_over
    }

    /// CLOCK_MONOTONIC (ns) at which the frame after the last published one was due, from
    /// the last chunk's capture time and the nominal rate (None before the first chunk): where
    /// a successor's capture must pick the timeline up.
    pub fn next_frame_due_ns(&self) -> Option<u64> {
        let lfi = self.last_frame_index();
        let nfpc = u64::from(self.geometry.frames_per_chunk);
        if lfi == 0 || nfpc == 0 {
            return None;
        }
        let table = self.mapping.chunk_table(&self.layout, self.geometry.chunks_on_port);
        let e = &table[(((lfi - 1) / nfpc) % u64::from(self.geometry.chunks_on_port)) as usize];
        if e.first_frame.load(Relaxed) != lfi + 1 - nfpc {
            return None;
        }
        let ns = nfpc * 1_000_000_000 / u64::from(self.geometry.sample_rate.max(1));
        e.mono_ns.load(Relaxed).checked_add(ns)
    }

    /// A descriptor of the port open for writing (for the service manager's store), which
    /// [`Writer::resume`] takes back.
    pub fn writable_fd(&self) -> Result<std::os::fd::OwnedFd> {
        self.file.try_clone().map(Into::into).map_err(|e| Error::io("dup of the port descriptor", e))
    }
}
