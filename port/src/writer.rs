//! The port writer: creates a port (a file in the runtime directory, or a sealed memfd, see
//! [`crate::memfd`]) and publishes chunks into it.
//!
//! Used by the broker, and through the C ABI by simulators and test rigs.

use std::fs::File;
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering::{Relaxed, Release};
use std::sync::Arc;

use crate::error::{Error, Result};
use crate::format::{self, ChunkEntry, ChunkExt, Geometry, Header, Layout, State};
use crate::memfd;
use crate::paths;
use crate::portfile;
use crate::ring::{self, Ring, Source};
use crate::shm::Mapping;
use crate::sys;
use crate::waker::Waker;

mod lead;
mod pending;
mod replica;
mod resume;

pub use pending::PendingPort;
use pending::{split_port_path, Place, Previous};

/// Parameters of a new port.
#[derive(Clone, Debug)]
pub struct PortParams {
    /// Geometry (channels, rate, nFPC, nCOP).
    pub geometry: Geometry,
    /// Device name recorded in the header.
    pub device: String,
    /// Group owning the file (mode 0640), if not the creator's.
    pub group: Option<u32>,
}

/// Timestamps and flags of a chunk.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ChunkMeta {
    /// CLOCK_MONOTONIC (ns) of the chunk's first frame; 0 = now.
    pub mono_ns: u64,
    /// CLOCK_REALTIME (ns) of the chunk's first frame; 0 = now.
    pub realtime_ns: u64,
    /// [`format::chunk_flags`].
    pub flags: u32,
    /// Bound (ns) of the timestamps' error: the first frame's true capture time lies within
    /// `mono_ns ± bound_ns`; None = not known (see [`format::ChunkExt::bound_ns`]).
    pub bound_ns: Option<u64>,
    /// Channels whose frames in this chunk are not real ([`format::ChunkExt::missing_channels`]).
    pub missing_channels: u64,
    /// Channels not yet aligned within their bound ([`format::ChunkExt::unaligned_channels`]).
    pub unaligned_channels: u64,
}

/// What holds a port's memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backing {
    /// A file in the runtime directory: readers open it by path; it outlives its writer, so
    /// the last window can be read after a broker crash. Readers check its size on every
    /// call (a shrunk file would kill them with SIGBUS).
    File,
    /// A sealed memfd (see [`crate::memfd`]): no path; readers get a descriptor from the
    /// broker; its size cannot change, so readers skip the size check; it lives only while
    /// a writer or a reader holds it.
    Memfd,
}

/// Writes one port. One writer per port; not shareable between threads without a lock.
pub struct Writer {
    mapping: Arc<Mapping>,
    waker: Waker,
    /// How far ahead of real time it publishes (for far waiters: `writer/lead.rs`).
    lead: lead::Lead,
    file: File,
    backing: Backing,
    path: PathBuf,
    geometry: Geometry,
    layout: Layout,
    epoch: u64,
    /// Left to a successor ([`Writer::leave_to_successor`]): dropping it changes nothing.
    handed_over: bool,
}

impl Writer {
    /// Creates the port `name` in the runtime directory (see [`paths::runtime_dir`]).
    pub fn create(name: &str, params: &PortParams) -> Result<Writer> {
        Writer::prepare(name, params)?.commit()
    }

    /// Creates a port file at `path`, replacing (and marking superseded) any port there.
    ///
    /// The file is built under a temporary name and renamed into place, and its version is
    /// written last, so no reader ever sees a half-initialised header.
    ///
    /// Create a writer, publish (a simulator or test rig; the broker is the writer in
    /// production):
    ///
    /// ```
    /// use bassport::format::chunk_flags;
    /// use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, State, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-create-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// let path = dir.join("bass-sim.port");
    /// let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 480, chunks_on_port: 10 };
    /// let params = PortParams { geometry, device: "sim".into(), group: None };
    /// let mut w = Writer::create_at(&path, &params)?;
    /// assert_eq!((w.state(), w.last_frame_index(), w.epoch()), (State::Starting, 0, 1));
    ///
    /// let chunk = vec![7i32; 480 * 2]; // frame-interleaved: L R L R ...
    /// assert_eq!(w.publish(Source::Interleaved(&chunk), ChunkMeta::default())?, 480);
    /// let gap = ChunkMeta { flags: chunk_flags::GAP, ..ChunkMeta::default() };
    /// assert_eq!(w.publish(Source::Interleaved(&vec![0; 960]), gap)?, 960);
    ///
    /// let info = Port::open_path(&path)?.info()?;
    /// assert_eq!((info.state, info.last_frame_index, info.chunks_published), (Some(State::Capturing), 960, 2));
    /// w.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn create_at(path: &Path, params: &PortParams) -> Result<Writer> {
        Writer::prepare_at(path, params)?.commit()
    }

    /// Builds the port `name` without publishing it: see [`Writer::prepare_at`].
    pub fn prepare(name: &str, params: &PortParams) -> Result<PendingPort> {
        Writer::prepare_at(&paths::port_path(name)?, params)
    }

    /// Builds a complete port file for `path` under a temporary name — checked against the
    /// free space, wholly allocated, header written except its epoch and version — and
    /// touches nothing else: any port at `path` is only inspected. The broker prepares the
    /// new port before it stops the old acquisition, so an Acquire that cannot have its port
    /// fails with the old one intact. [`PendingPort::commit`] publishes it; dropping the
    /// pending port removes the temporary file.
    pub fn prepare_at(path: &Path, params: &PortParams) -> Result<PendingPort> {
        let geometry = params.geometry.clone();
        let layout = geometry.layout()?;
        let (dir_path, name) = split_port_path(path)?;
        let dir = portfile::open_dir(&dir_path)?;
        let previous = Previous::inspect(&dir, &name, path)?;
        portfile::remove_stale_temps(&dir, &dir_path, &name);
        portfile::check_space(&dir, &dir_path, layout.mapped_size)?;
        let (tmp_name, file) = portfile::create_temp(&dir, &dir_path, &name)?;
        let mut pending = PendingPort {
            place: Place::File { dir, dir_path, name, tmp_name: Some(tmp_name) },
            path: path.to_owned(),
            file,
            mapping: None,
            geometry,
            layout,
            previous,
            after: None,
        };
        pending.build(params)?;
        Ok(pending)
    }

    /// Builds the port `name` as a sealed memfd (see [`crate::memfd`]) without publishing it.
    ///
    /// Nothing is created in the runtime directory. The epoch continues from
    /// `previous_epoch` (the port of the same name this one replaces, which the caller holds
    /// and marks superseded) or from a port file of that name left there, whichever is
    /// newer; [`PendingPort::commit`] marks such a left-over file superseded and removes it,
    /// so that no reader opening the name by path finds a port that will never move again.
    pub fn prepare_memfd(
        name: &str,
        params: &PortParams,
        previous_epoch: Option<u64>,
    ) -> Result<PendingPort> {
        Writer::prepare_memfd_sealed(name, params, previous_epoch, false)
    }

    /// [`Writer::prepare_memfd`] for a port a successor may take back ([`Writer::resume`]):
    /// sealed without `F_SEAL_FUTURE_WRITE`, the memfd's mode 0600 keeping other users from
    /// reopening a reader's descriptor writable (see [`memfd::seal_resumable`]).
    pub fn prepare_memfd_resumable(
        name: &str,
        params: &PortParams,
        previous_epoch: Option<u64>,
    ) -> Result<PendingPort> {
        Writer::prepare_memfd_sealed(name, params, previous_epoch, true)
    }

    fn prepare_memfd_sealed(
        name: &str,
        params: &PortParams,
        previous_epoch: Option<u64>,
        resumable: bool,
    ) -> Result<PendingPort> {
        let path = paths::port_path(name)?;
        let geometry = params.geometry.clone();
        let layout = geometry.layout()?;
        let (dir_path, file_name) = split_port_path(&path)?;
        // A left-over port file (of a file-backed run): only looked at, replaced at commit.
        let dir = portfile::open_dir(&dir_path).ok();
        let previous = match &dir {
            Some(d) => Previous::inspect(d, &file_name, &path)?,
            None => None,
        };
        let file = memfd::create(name, layout.mapped_size)?;
        let mut pending = PendingPort {
            place: Place::Memfd { dir, name: file_name, resumable },
            path,
            file,
            mapping: None,
            geometry,
            layout,
            previous,
            after: previous_epoch,
        };
        pending.build(params)?;
        Ok(pending)
    }

    /// Path of the port file (for a memfd port: the path a file port of that name would
    /// have; nothing is there).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What holds the port's memory.
    pub fn backing(&self) -> Backing {
        self.backing
    }

    /// For a memfd port, a new read-only descriptor of it for one reader (see
    /// [`memfd::reopen_read_only`]); None for a file port (readers open its path).
    pub fn reader_fd(&self) -> Result<Option<OwnedFd>> {
        match self.backing {
            Backing::File => Ok(None),
            Backing::Memfd => memfd::reopen_read_only(&self.file).map(Some),
        }
    }

    /// The port's geometry.
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// The port's layout.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The acquisition epoch of this port.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    fn header(&self) -> &Header {
        self.mapping.header()
    }

    /// Index of the newest published frame.
    pub fn last_frame_index(&self) -> u64 {
        self.header().last_frame_index.load(Relaxed)
    }

    /// Publishes one chunk of nFPC frames. Returns the new last frame index.
    ///
    /// The chunk comes frame-interleaved ([`Source::Interleaved`], nFPC × channels samples)
    /// or as one slice of nFPC samples per channel ([`Source::Planar`]); `meta` carries its
    /// timestamps (0: now) and [`format::chunk_flags`]. Readers waiting for its frames wake.
    ///
    /// ```
    /// use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-publish-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// # let path = dir.join("bass-doc.port");
    /// let geometry = Geometry { channels: 2, sample_rate: 8000, frames_per_chunk: 2, chunks_on_port: 4 };
    /// let mut w = Writer::create_at(&path, &PortParams { geometry, device: "doc".into(), group: None })?;
    /// w.publish(Source::Interleaved(&[1, -1, 2, -2]), ChunkMeta::default())?;
    /// let lfi = w.publish(Source::Planar(&[&[3, 4], &[-3, -4]]), ChunkMeta::default())?;
    /// assert_eq!(lfi, 4);
    /// // A chunk of the wrong size is refused, naming the sizes.
    /// assert!(w.publish(Source::Interleaved(&[1, 2, 3]), ChunkMeta::default()).is_err());
    ///
    /// let port = Port::open_path(&path)?;
    /// let (mut l, mut r, mut nfr) = (vec![0; 4], vec![0; 4], 1);
    /// port.get_audio_data(4, &mut nfr, &mut [&mut l, &mut r])?;
    /// assert_eq!((l, r), (vec![1, 2, 3, 4], vec![-1, -2, -3, -4]));
    /// # drop(port);
    /// # w.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn publish(&mut self, src: Source<'_>, meta: ChunkMeta) -> Result<u64> {
        let nfpc = self.geometry.frames_per_chunk as usize;
        let channels = self.geometry.channels as usize;
        match &src {
            Source::Interleaved(s) if s.len() != nfpc * channels => {
                return Err(Error::InvalidArgument(format!(
                    "interleaved chunk of {} samples; this port needs {nfpc} frames x {channels} channels = {}",
                    s.len(),
                    nfpc * channels
                )))
            }
            Source::Planar(p) if p.len() != channels => {
                return Err(Error::InvalidArgument(format!(
                    "planar chunk with {} channels; this port has {channels}",
                    p.len()
                )))
            }
            Source::Planar(p) => {
                if let Some((c, s)) = p.iter().enumerate().find(|(_, s)| s.len() != nfpc) {
                    return Err(Error::InvalidArgument(format!(
                        "planar chunk: channel {c} has {} frames; this port needs {nfpc}",
                        s.len()
                    )));
                }
            }
            _ => {}
        }
        let h = self.mapping.header();
        let lfi = h.last_frame_index.load(Relaxed);
        if lfi + nfpc as u64 > format::MAX_FRAME_INDEX {
            return Err(Error::InvalidArgument(format!("frame index {lfi} would pass the format's limit")));
        }
        let table = self.mapping.chunk_table(&self.layout, self.geometry.chunks_on_port);
        let slot = ((lfi / nfpc as u64) % u64::from(self.geometry.chunks_on_port)) as usize;
        let entry = &table[slot];
        let ext = self.mapping.chunk_ext(&self.layout, self.geometry.chunks_on_port).map(|x| &x[slot]);
        let ring = Ring {
            last_frame_index: &h.last_frame_index,
            write_intent: &h.write_intent,
            samples: self.mapping.samples(&self.layout, self.geometry.channels),
            frames_on_port: self.layout.frames_on_port,
        };
        // The lines this publish writes, fetched together before the first store (after the
        // writer slept they are usually cold, and each would otherwise be a miss of its own
        // between the caller's stamp and the readers' wake).
        ring::prefetch_write(&h.futex);
        ring::prefetch_write(entry);
        if let Some(x) = ext {
            ring::prefetch_write(x);
        }
        ring.prefetch_publish(lfi, nfpc, channels);
        let mono = if meta.mono_ns == 0 { sys::monotonic_ns() } else { meta.mono_ns };
        let real = if meta.realtime_ns == 0 { sys::realtime_ns() } else { meta.realtime_ns };
        let new_lfi = ring.publish(lfi, nfpc, channels, &src, || {
            write_entry(entry, ext, lfi + 1, Stamp { mono, real, meta: &meta }, nfpc as u32);
        });
        h.chunks_published.fetch_add(1, Relaxed);
        if matches!(src, Source::Zeros) {
            h.gap_frames.fetch_add(nfpc as u64, Relaxed);
        }
        let bits = if matches!(State::from_u32(h.state.load(Relaxed)), Some(State::Idle | State::Starting)) {
            h.state.store(State::Capturing as u32, Release);
            u32::MAX
        } else {
            sys::chunk_bit(lfi / nfpc as u64) | self.lead.take_far_bit()
        };
        h.futex.fetch_add(1, Release);
        self.waker.wake(bits);
        // After the wake, so that its clock read is not between the frames and the readers:
        // the heartbeat is a liveness sign, which waiting readers look at once per liveness
        // slice (100 ms), not a timestamp of the chunk; the lead is for the next publish.
        let now = sys::monotonic_ns();
        h.heartbeat_mono_ns.store(now, Relaxed);
        self.lead.published(now);
        self.check_intact()?;
        Ok(new_lfi)
    }

    /// `Corrupt` if the port file shrank under the writer's (guarded) mapping: the SIGBUS
    /// guard replaced it with zero pages, so what was published since reaches no reader.
    pub(crate) fn check_intact(&self) -> Result<()> {
        if !self.mapping.broken() {
            return Ok(());
        }
        Err(Error::Corrupt(format!(
            "the port file {} shrank under the writer: its mapping was replaced by zero pages \
             that no reader sees; this port cannot be published any more",
            self.path.display()
        )))
    }

    /// Whether the last wake of the readers was handed to the wake thread (many readers
    /// waiting) rather than made by the writer itself; see [`crate::waker`].
    pub fn wakes_through_helper(&self) -> bool {
        !self.waker.is_direct()
    }

    /// How many reader wake-ups this writer's own thread made (the rest, with many readers,
    /// are the wake thread's); see [`crate::waker`].
    pub fn readers_woken_by_writer(&self) -> u64 {
        self.waker.woken_by_writer()
    }

    /// Sets the state (with an error code and message for [`State::Error`]) and wakes readers.
    pub fn set_state(&self, state: State, code: u32, message: &str) {
        let h = self.header();
        format::write_text(&h.message, message);
        h.error_code.store(code, Relaxed);
        h.state.store(state as u32, Release);
        wake(h);
    }

    /// The current state.
    pub fn state(&self) -> State {
        State::from_u32(self.header().state.load(Relaxed)).unwrap_or(State::Error)
    }

    /// Counts `n` recovered device overruns.
    pub fn add_xruns(&self, n: u64) {
        self.header().xruns.fetch_add(n, Relaxed);
    }

    /// Counts `n` zero-filled frames published inside data chunks (a gap that did not span a
    /// whole chunk); whole zero chunks (`Source::Zeros`) are counted by `publish`.
    pub fn add_gap_frames(&self, n: u64) {
        self.header().gap_frames.fetch_add(n, Relaxed);
    }

    /// Publishes the device-clock rate estimate (Hz).
    pub fn set_rate_estimate(&self, hz: f64) {
        let mhz = if hz.is_finite() && hz > 0.0 { (hz * 1000.0).round() as u64 } else { 0 };
        self.header().rate_estimate_mhz.store(mhz, Relaxed);
    }

    /// Records that the writer is alive without publishing.
    pub fn heartbeat(&self) {
        self.header().heartbeat_mono_ns.store(sys::monotonic_ns(), Relaxed);
    }

    /// Stops the acquisition: the port keeps its frames and shows [`State::Stopped`].
    pub fn stop(&self) {
        if !self.handed_over && matches!(self.state(), State::Idle | State::Starting | State::Capturing) {
            self.set_state(State::Stopped, format::error_code::NONE, "");
        }
    }

    /// Stops an acquisition that ended on an error: the port shows [`State::Stopped`] (the
    /// window stays), its error code is cleared and its message says what ended it.
    /// Returns the error message it cleared, or None when the port was not in error.
    pub fn clear_error(&self) -> Option<String> {
        if self.state() != State::Error {
            return None;
        }
        let old = format::read_text(&self.header().message);
        self.set_state(State::Stopped, format::error_code::NONE, &format!("stopped after an error: {old}"));
        Some(old)
    }

    /// Stops and removes the port file (readers that have it mapped keep their view). A
    /// memfd port has no file: it is only stopped, and goes when its last holder closes it.
    pub fn remove(self) -> Result<()> {
        self.stop();
        if self.backing == Backing::Memfd {
            return Ok(());
        }
        std::fs::remove_file(&self.path).map_err(|e| Error::io(format!("remove {}", self.path.display()), e))
    }
}

impl Drop for Writer {
    fn drop(&mut self) {
        self.stop();
    }
}

fn wake(h: &Header) {
    h.futex.fetch_add(1, Release);
    sys::futex_wake_all(&h.futex);
}

/// A chunk's timestamps (0 in `meta` already replaced by now) and the rest of its meta.
struct Stamp<'a> {
    mono: u64,
    real: u64,
    meta: &'a ChunkMeta,
}

/// Writes a chunk's table row and, if the port has the extension table, its extension row
/// (both before the chunk's frames are published: a reader that sees the frames sees them).
fn write_entry(e: &ChunkEntry, x: Option<&ChunkExt>, first: u64, s: Stamp<'_>, frames: u32) {
    e.first_frame.store(first, Relaxed);
    e.mono_ns.store(s.mono, Relaxed);
    e.realtime_ns.store(s.real, Relaxed);
    e.flags.store(s.meta.flags, Relaxed);
    e.frames.store(frames, Relaxed);
    if let Some(x) = x {
        x.first_frame.store(first, Relaxed);
        x.bound_ns.store(s.meta.bound_ns.unwrap_or(format::BOUND_UNKNOWN), Relaxed);
        x.missing_channels.store(s.meta.missing_channels, Relaxed);
        x.unaligned_channels.store(s.meta.unaligned_channels, Relaxed);
    }
}
