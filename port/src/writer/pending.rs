//! A port prepared under a temporary name (or in a sealed memfd) and put in place by its
//! commit, so that a failed Acquire leaves the running port untouched; and the header's
//! initialisation, in two steps around that commit.

use std::fs::File;
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering::{Relaxed, Release};
use std::sync::Arc;

use super::{wake, Backing, PortParams, Writer};
use crate::error::{Error, Result};
use crate::format::{self, Geometry, Header, Layout, State};
use crate::memfd;
use crate::portfile;
use crate::shm::Mapping;
use crate::sys;
use crate::waker::Waker;

/// Where a pending port lives until it is committed.
pub(super) enum Place {
    /// A file built under a temporary name in `dir`, renamed to `name` by the commit.
    File { dir: OwnedFd, dir_path: PathBuf, name: String, tmp_name: Option<String> },
    /// A sealed memfd; a left-over port file `name` in `dir` (if any) is removed by the commit.
    /// `resumable`: sealed without `F_SEAL_FUTURE_WRITE`, so a successor can map it writable
    /// again (see [`memfd::seal_resumable`]).
    Memfd { dir: Option<OwnedFd>, name: String, resumable: bool },
}

/// A port built by [`Writer::prepare_at`] but not yet in place: its file exists only under a
/// temporary name, which is removed if the pending port is dropped.
pub struct PendingPort {
    pub(super) place: Place,
    pub(super) path: PathBuf,
    pub(super) file: File,
    pub(super) mapping: Option<Mapping>,
    pub(super) geometry: Geometry,
    pub(super) layout: Layout,
    pub(super) previous: Option<Previous>,
    /// An epoch the new port must pass whatever the file at its path says (the writer's
    /// memory of the port it replaces: that file may have been cut or removed).
    pub(super) after: Option<u64>,
}

impl PendingPort {
    pub(super) fn build(&mut self, params: &PortParams) -> Result<()> {
        if let Place::File { dir_path, .. } = &self.place {
            portfile::set_mode_group(&self.file, params.group)?;
            portfile::allocate(&self.file, dir_path, self.layout.mapped_size)?;
        }
        let mut mapping = Mapping::new(&self.file, self.layout.mapped_size, true)?;
        if matches!(self.place, Place::File { .. }) {
            // Its owner or root can shrink a port file under the writer too: guarded, a
            // publish then fails (Corrupt) instead of the broker dying of SIGBUS.
            mapping.guard();
        }
        init_header(mapping.header(), &self.geometry, &self.layout, &params.device);
        if let Place::Memfd { resumable, .. } = self.place {
            // Allocated (memfd::create) and mapped writable: from here on its size is final
            // and nobody gains write access to it (but a successor, if resumable).
            if resumable {
                memfd::seal_resumable(&self.file)?;
            } else {
                memfd::seal(&self.file)?;
            }
        }
        self.mapping = Some(mapping);
        Ok(())
    }

    /// Bytes the port file occupies (all allocated).
    pub fn size(&self) -> u64 {
        self.layout.mapped_size
    }

    /// The epoch of the port this one replaces, if any.
    pub fn previous_epoch(&self) -> Option<u64> {
        self.previous.as_ref().map(|p| p.epoch).max(self.after)
    }

    /// Makes the new port's epoch pass `epoch` (the port it replaces, as its writer knows it)
    /// even if the file at the path no longer says so.
    pub fn after_epoch(&mut self, epoch: Option<u64>) {
        self.after = self.after.max(epoch);
    }

    /// Publishes the port: epoch (the previous port's + 1), writer, version last, then the
    /// rename into place; the port it replaces is marked superseded (its readers keep its
    /// window).
    pub fn commit(mut self) -> Result<Writer> {
        let mapping = self.mapping.take().ok_or_else(|| Error::InvalidArgument("port not built".into()))?;
        let epoch = self.previous_epoch().map_or(1, |e| e + 1);
        finish_header(mapping.header(), epoch);
        let backing = match &mut self.place {
            Place::File { dir, dir_path, name, tmp_name } => {
                let tmp = tmp_name.take().unwrap_or_default();
                if let Err(e) = rustix::fs::renameat(&*dir, tmp.as_str(), &*dir, name.as_str()) {
                    let _ = rustix::fs::unlinkat(&*dir, tmp.as_str(), rustix::fs::AtFlags::empty());
                    return Err(Error::io(
                        format!("rename {tmp} to {name} in {}", dir_path.display()),
                        e.into(),
                    ));
                }
                Backing::File
            }
            Place::Memfd { dir, name, .. } => {
                if let (Some(dir), Some(_)) = (dir.as_ref(), self.previous.as_ref()) {
                    let _ = rustix::fs::unlinkat(dir, name.as_str(), rustix::fs::AtFlags::empty());
                }
                Backing::Memfd
            }
        };
        if let Some(p) = self.previous.take() {
            p.supersede();
        }
        let file = self.file.try_clone().map_err(|e| Error::io("dup of the port file", e))?;
        let mapping = Arc::new(mapping);
        let waker = Waker::new(mapping.clone());
        Ok(Writer {
            mapping,
            waker,
            lead: super::lead::Lead::new(self.geometry.chunk_ns()),
            file,
            backing,
            path: self.path.clone(),
            geometry: self.geometry.clone(),
            layout: self.layout,
            epoch,
            handed_over: false,
        })
    }
}

impl Drop for PendingPort {
    fn drop(&mut self) {
        if let Place::File { dir, tmp_name, .. } = &mut self.place {
            if let Some(tmp) = tmp_name.take() {
                let _ = rustix::fs::unlinkat(&*dir, tmp.as_str(), rustix::fs::AtFlags::empty());
            }
        }
    }
}

/// The directory of a port path and the port's file name in it.
pub(super) fn split_port_path(path: &Path) -> Result<(PathBuf, String)> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .and_then(|f| f.to_str())
        .ok_or_else(|| Error::InvalidArgument(format!("port path {} has no file name", path.display())))?
        .to_owned();
    Ok((dir, name))
}

/// Writes everything but the epoch, the writer's identity and the version.
pub(super) fn init_header(h: &Header, g: &Geometry, l: &Layout, device: &str) {
    h.magic.store(format::MAGIC, Relaxed);
    h.version_minor.store(format::VERSION_MINOR, Relaxed);
    h.header_size.store(format::HEADER_SIZE as u32, Relaxed);
    h.channels.store(g.channels, Relaxed);
    h.sample_format.store(format::SAMPLE_FORMAT_S32, Relaxed);
    h.sample_rate.store(g.sample_rate, Relaxed);
    h.frames_per_chunk.store(g.frames_per_chunk, Relaxed);
    h.chunks_on_port.store(g.chunks_on_port, Relaxed);
    h.chunk_table_offset.store(l.chunk_table_offset, Relaxed);
    h.samples_offset.store(l.samples_offset, Relaxed);
    h.total_size.store(l.total_size, Relaxed);
    h.ext_table_offset.store(l.ext_table_offset, Relaxed);
    h.state.store(State::Starting as u32, Relaxed);
    format::write_text(&h.device, device);
}

/// Completes a header prepared by [`init_header`]: epoch, writer, clocks, and the version
/// last (Release: a reader that sees the version sees everything above).
pub(super) fn finish_header(h: &Header, epoch: u64) {
    h.epoch.store(epoch, Relaxed);
    h.writer_pid.store(std::process::id(), Relaxed);
    h.writer_start_time.store(sys::own_start_time(), Relaxed);
    h.writer_pid_ns.store(sys::own_pid_ns().unwrap_or(0), Relaxed);
    h.created_realtime_ns.store(sys::realtime_ns(), Relaxed);
    let now = sys::monotonic_ns();
    h.started_mono_ns.store(now, Relaxed);
    h.heartbeat_mono_ns.store(now, Relaxed);
    h.version_major.store(format::VERSION_MAJOR, Release);
}

/// A port file found where a new one is being created.
pub(super) struct Previous {
    mapping: Mapping,
    epoch: u64,
}

impl Previous {
    /// Looks at an existing file, relative to the directory and without following a link:
    /// a symbolic link, a non-regular file or a file of another owner is refused (see
    /// [`portfile::open_existing`]); a live port of another process is an error; a valid
    /// port is remembered so its epoch continues and its readers can be told; anything else
    /// (stale garbage of our own user) is simply replaced.
    pub(super) fn inspect(dir: &OwnedFd, name: &str, path: &Path) -> Result<Option<Previous>> {
        let Some((file, len)) = portfile::open_existing(dir, name, path)? else {
            return Ok(None);
        };
        let Ok(mapping) = Mapping::new(&file, len, true) else { return Ok(None) };
        let h = mapping.header();
        if format::validate(h, len).is_err() {
            return Ok(None);
        }
        let pid = h.writer_pid.load(Relaxed);
        let start = h.writer_start_time.load(Relaxed);
        let state = h.state.load(Relaxed);
        let live = matches!(State::from_u32(state), Some(State::Idle | State::Starting | State::Capturing));
        if live && pid != std::process::id() && sys::writer_alive(pid, start) {
            return Err(Error::InvalidArgument(format!(
                "port {} is being written by live process {pid}",
                path.display()
            )));
        }
        let epoch = h.epoch.load(Relaxed);
        Ok(Some(Previous { mapping, epoch }))
    }

    pub(super) fn supersede(self) {
        let h = self.mapping.header();
        h.state.store(State::Superseded as u32, Release);
        wake(h);
    }
}
