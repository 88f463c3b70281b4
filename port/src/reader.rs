//! The port reader: opens a port read-only and reads blocks with the formal
//! `getAudioData` algorithm, waits for frames, reads chunk metadata and zero-copy views.
//!
//! A `Port` holds no mutable state (the next frame to read belongs to the caller), so
//! one `Port` may be shared by any number of threads.

use std::fs::{File, OpenOptions};
use std::os::fd::{AsFd, OwnedFd};
use std::os::unix::fs::{MetadataExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::sync::atomic::{fence, Ordering::Acquire, Ordering::Relaxed};
use std::time::Duration;

use crate::error::{Error, Result};
use crate::format::{self, Geometry, Header, Layout, State};
use crate::memfd;
use crate::paths;
use crate::ring::{ChannelRing, Plan, Ring};
use crate::shm::Mapping;
use crate::sys::{self, FutexWait};

mod info;
mod liveness;
mod stream_reads;
mod types;

pub use types::{ChunkInfo, PortInfo, Read, View};

/// How long a writer in another pid namespace may leave its heartbeat unrefreshed (plus two
/// chunk periods) before its readers count it as gone: its pid cannot be looked up there.
pub const FOREIGN_WRITER_SILENCE: Duration = Duration::from_secs(2);

/// Longest futex wait between two checks that the writer process still exists.
pub const LIVENESS_SLICE: Duration = Duration::from_millis(100);
const LIVENESS_SLICE_NS: u64 = LIVENESS_SLICE.as_nanos() as u64;

/// How long a port file may stay unwritten (format version 0) after it last changed before
/// an opener stops reporting `NotReady` (retry) and reports `NeverReady` (give up). A writer
/// of this library never shows version 0 under the port's name at all (it renames a
/// complete file into place), so this only bounds the wait on stale or foreign files.
pub const NOT_READY_GRACE: Duration = Duration::from_secs(2);

/// The error of a port whose file shrank under the reader's mapping.
fn shrank(mapping: &Mapping) -> Error {
    Error::Corrupt(format!(
        "the port file shrank under the reader (its {} mapped bytes are no longer all there); \
         the port cannot be read any more through this handle: open it again",
        mapping.len()
    ))
}

/// `NotReady` while the file changed within [`NOT_READY_GRACE`], else `NeverReady`.
fn not_ready(path: &Path, meta: &std::fs::Metadata) -> Error {
    let changed_ns = |s: i64, ns: i64| (s.max(0) as u128) * 1_000_000_000 + ns.max(0) as u128;
    let last = changed_ns(meta.mtime(), meta.mtime_nsec()).max(changed_ns(meta.ctime(), meta.ctime_nsec()));
    let now = u128::from(sys::realtime_ns());
    let age_ms = (now.saturating_sub(last) / 1_000_000) as u64;
    if age_ms >= NOT_READY_GRACE.as_millis() as u64 {
        Error::NeverReady { path: path.to_owned(), age_ms }
    } else {
        Error::NotReady
    }
}

/// An open port (read-only mapping).
pub struct Port {
    mapping: Mapping,
    file: File,
    path: PathBuf,
    geometry: Geometry,
    layout: Layout,
    epoch: u64,
    version_minor: u32,
    /// The size is sealed (a memfd port): no per-call size check.
    sealed: bool,
    /// Whether the writer lives (a pidfd opened once).
    watch: liveness::WriterWatch,
    /// The broker that handed this memfd port over (None: a port file, or a descriptor of
    /// unknown origin): asked, once its writer is dead, whether a successor replaced it.
    broker: Option<String>,
}

impl Port {
    /// Opens the port `name` in the runtime directory. The file must be owned by a user
    /// the reader trusts ([`paths::expected_port_owners`]: root or the reader itself, or
    /// `$BASS_BROKER_UID`), else [`Error::WrongOwner`]: a port name in a directory others can
    /// write may have been taken by an impostor.
    ///
    /// When there is no port file of that name (a broker running with `--port-backing
    /// memfd`), the broker `name` is asked for its port's descriptor over its control socket
    /// (`open-port`, see docs/control-protocol.md); a broker that answers with a plain file,
    /// an older broker, or none at all leaves the path's answer (usually `NotFound`).
    ///
    /// Open a port, wait for a frame, read (here the port comes from a [`Writer`] in a
    /// private runtime directory; in production the broker writes it):
    ///
    /// ```
    /// use std::time::Duration;
    /// use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-open-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// # std::env::set_var("BASS_RUNTIME_DIR", &dir);
    /// let geometry = Geometry { channels: 2, sample_rate: 48000, frames_per_chunk: 4, chunks_on_port: 8 };
    /// let mut w = Writer::create("doc", &PortParams { geometry, device: "doc".into(), group: None })?;
    ///
    /// let port = Port::open("doc")?; // the broker's name: $BASS_RUNTIME_DIR/bass-doc.port
    /// w.publish(Source::Interleaved(&[10, 20, 11, 21, 12, 22, 13, 23]), ChunkMeta::default())?;
    /// let last = port.wait(4, Duration::from_secs(1))?; // frames are numbered from 1
    /// assert_eq!(last, 4);
    /// let (mut left, mut right, mut nfr) = (vec![0; 4], vec![0; 4], 1);
    /// let r = port.get_audio_data(4, &mut nfr, &mut [&mut left, &mut right])?;
    /// assert_eq!((r.frames, r.loss, nfr), (4, 0, 5));
    /// assert_eq!((left, right), (vec![10, 11, 12, 13], vec![20, 21, 22, 23]));
    /// # drop(port);
    /// # w.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn open(name: &str) -> Result<Port> {
        let path = paths::port_path(name)?;
        let by_path = Port::open_path_named(&path, name, Some(&paths::expected_port_owners()?));
        if !matches!(by_path, Err(Error::NotFound { .. })) {
            return by_path;
        }
        match crate::control::client::port_from_broker(name) {
            Ok(Some(port)) => Ok(port),
            // The broker refused this client, or the system refused it the broker's socket:
            // say so rather than "no port".
            Err(e @ Error::Broker(_)) => Err(e),
            Err(e @ Error::NoBroker { .. }) if e.is_access_refused() => Err(e),
            Ok(None) | Err(_) => by_path,
        }
    }

    /// Maps the port held by `fd` (a descriptor handed over by a broker, or any open port
    /// file), validated exactly like a port opened by path; `name` is used in messages.
    ///
    /// If the descriptor's size is sealed (`F_SEAL_SHRINK | F_SEAL_GROW`: a memfd port), the
    /// size is checked once here and never again; otherwise it is treated like a file and
    /// checked before every access.
    pub fn from_fd(fd: OwnedFd, name: &str) -> Result<Port> {
        let sealed = memfd::size_sealed(fd.as_fd());
        let file = File::from(fd);
        let meta = file.metadata().map_err(|e| Error::io("fstat of the port descriptor", e))?;
        if !meta.file_type().is_file() {
            return Err(Error::Corrupt(format!("the descriptor for port {name} is not a regular file")));
        }
        let path = paths::port_path(name).unwrap_or_else(|_| PathBuf::from(name));
        let mut port = Port::map(file, &path, &meta, sealed)?;
        if sealed && paths::check_name(name).is_ok() {
            port.broker = Some(name.to_owned());
        }
        Ok(port)
    }

    /// Opens the port file at `path` (the caller chose the file: its owner is not checked).
    ///
    /// ```
    /// use bassport::{Error, Geometry, Port, PortParams, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-open-path-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// let path = dir.join("bass-doc.port");
    /// assert!(matches!(Port::open_path(&path), Err(Error::NotFound { .. })));
    /// let geometry = Geometry { channels: 1, sample_rate: 8000, frames_per_chunk: 100, chunks_on_port: 10 };
    /// let w = Writer::create_at(&path, &PortParams { geometry: geometry.clone(), device: "doc".into(), group: None })?;
    /// let port = Port::open_path(&path)?;
    /// assert_eq!((port.geometry(), port.frames_on_port()), (&geometry, 1000));
    /// # drop(port);
    /// # w.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn open_path(path: &Path) -> Result<Port> {
        Port::open_path_named(path, &path.display().to_string(), None)
    }

    fn open_path_named(path: &Path, name: &str, owners: Option<&[u32]>) -> Result<Port> {
        // By name: never through a symbolic link (nothing of bass puts one there).
        let flags = if owners.is_some() { libc::O_CLOEXEC | libc::O_NOFOLLOW } else { libc::O_CLOEXEC };
        let file = match OpenOptions::new().read(true).custom_flags(flags).open(path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(Error::NotFound { name: name.to_owned(), path: path.to_owned() })
            }
            Err(e) if e.raw_os_error() == Some(libc::ELOOP) => {
                return Err(Error::Corrupt(format!(
                    "{} is a symbolic link; a port opened by name is never read through a link \
                     (another user may have planted it)",
                    path.display()
                )))
            }
            Err(e) => {
                let e = crate::access::refused(crate::access::Kind::Port, path, e);
                return Err(Error::io(format!("open {}", path.display()), e));
            }
        };
        let meta = file.metadata().map_err(|e| Error::io("fstat of the port file", e))?;
        if let Some(owners) = owners {
            if !owners.contains(&meta.uid()) {
                let expected =
                    owners.iter().map(|&u| paths::describe_uid(u)).collect::<Vec<_>>().join(" or ");
                return Err(Error::WrongOwner {
                    path: path.to_owned(),
                    owner: paths::describe_uid(meta.uid()),
                    expected,
                });
            }
        }
        // A port file is never treated as sealed (a file system's files cannot carry seals).
        Port::map(file, path, &meta, false)
    }

    /// Maps `file` (`meta` its fstat) and validates the header against its length.
    fn map(file: File, path: &Path, meta: &std::fs::Metadata, sealed: bool) -> Result<Port> {
        let len = meta.len();
        if len == 0 {
            return Err(Error::Corrupt(format!("{} is empty", path.display())));
        }
        let mut mapping = Mapping::new(&file, len, false)?;
        // A port file can shrink under the mapping, from before the header is read on.
        if !sealed {
            mapping.guard();
        }
        let v = format::validate(mapping.header(), len);
        if mapping.broken() {
            return Err(shrank(&mapping));
        }
        let v = match v {
            Err(Error::NotReady) => return Err(not_ready(path, meta)),
            other => other?,
        };
        let epoch = mapping.header().epoch.load(Relaxed);
        Ok(Port {
            mapping,
            file,
            path: path.to_owned(),
            geometry: v.geometry,
            layout: v.layout,
            epoch,
            version_minor: v.version_minor,
            sealed,
            watch: liveness::WriterWatch::default(),
            broker: None,
        })
    }

    /// Whether the port's size is sealed (a memfd port): reads skip the size check.
    pub fn size_sealed(&self) -> bool {
        self.sealed
    }

    /// Path of the port file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Geometry (fixed for the life of the port).
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// The open port file (read-only).
    pub fn file(&self) -> &File {
        &self.file
    }

    /// Bytes of the port file the header describes.
    pub fn size(&self) -> u64 {
        self.layout.mapped_size
    }

    /// nFOP.
    pub fn frames_on_port(&self) -> u64 {
        self.layout.frames_on_port
    }

    /// Acquisition epoch.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    fn header(&self) -> &Header {
        self.mapping.header()
    }

    fn ring(&self) -> Ring<'_> {
        let h = self.header();
        Ring {
            last_frame_index: &h.last_frame_index,
            write_intent: &h.write_intent,
            samples: self.mapping.samples(&self.layout, self.geometry.channels),
            frames_on_port: self.layout.frames_on_port,
        }
    }

    /// For a port file without the SIGBUS guard ([`crate::sigbus`]: off, or no slot): refuses a
    /// call on a file that has shrunk below its layout, before touching it (a shrink between
    /// this check and the access still raises SIGBUS). Nothing to do for a sealed port (it
    /// cannot shrink; its size was checked against the header when it was mapped) or a
    /// guarded one (a shrink shows as [`Port::check_intact`]'s broken mark, with no system
    /// call per call).
    fn check_size(&self) -> Result<()> {
        if self.sealed || self.mapping.guarded() {
            return Ok(());
        }
        // lseek(SEEK_END) returns the file's size like fstat, with less work per call than
        // std's statx (measured: the 1-reader wake latency 5–10 % lower, interleaved in one
        // run). The offset it moves is never used: the port is only accessed through the map.
        let len = rustix::fs::seek(&self.file, rustix::fs::SeekFrom::End(0))
            .map_err(|e| Error::io("lseek of the port file", e.into()))?;
        if len < self.layout.mapped_size {
            return Err(Error::Corrupt(format!(
                "port file shrank to {len} bytes under the reader (needs {})",
                self.layout.mapped_size
            )));
        }
        Ok(())
    }

    /// After the accesses of a call: `Corrupt` if the port file shrank under them (the SIGBUS
    /// guard then replaced the mapping with zero pages, so what was read is not the port's).
    /// No system call: an atomic load.
    fn check_intact(&self) -> Result<()> {
        if self.mapping.broken() {
            Err(shrank(&self.mapping))
        } else {
            Ok(())
        }
    }

    /// Loads the last frame index (Acquire) and checks it is plausible.
    fn last_frame_index(&self) -> Result<u64> {
        let lfi = self.header().last_frame_index.load(Acquire);
        if lfi > format::MAX_FRAME_INDEX {
            return Err(Error::Corrupt(format!("last frame index {lfi} is beyond the format's limit")));
        }
        Ok(lfi)
    }

    /// The formal `getAudioData`: copies up to `max` frames from `*nfr` into `out`, one slice
    /// per channel (channels `0..out.len()`), and advances `*nfr`. Never blocks.
    ///
    /// Every `out` slice must hold at least `min(max, nFOP)` samples.
    ///
    /// `*nfr` beyond the newest frame gives 0 frames; frames that already left the window are
    /// counted in [`Read::loss`] and the block starts at the oldest frame still there:
    ///
    /// ```
    /// use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-gad-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// # let path = dir.join("bass-doc.port");
    /// // A mono port of 2 chunks of 2 frames: the window holds the newest 4 frames.
    /// let geometry = Geometry { channels: 1, sample_rate: 8000, frames_per_chunk: 2, chunks_on_port: 2 };
    /// let mut w = Writer::create_at(&path, &PortParams { geometry, device: "doc".into(), group: None })?;
    /// let port = Port::open_path(&path)?;
    /// for chunk in [[1, 2], [3, 4], [5, 6]] {
    ///     w.publish(Source::Interleaved(&chunk), ChunkMeta::default())?;
    /// }
    /// let (mut out, mut nfr) = (vec![0; 4], 1);
    /// let r = port.get_audio_data(4, &mut nfr, &mut [&mut out])?;
    /// assert_eq!((r.frames, r.loss, nfr, &out[..]), (4, 2, 7, &[3, 4, 5, 6][..]));
    /// let r = port.get_audio_data(4, &mut nfr, &mut [&mut out])?; // nothing new yet
    /// assert_eq!((r.frames, r.loss, nfr), (0, 0, 7));
    /// # drop(port);
    /// # w.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn get_audio_data(&self, max: usize, nfr: &mut u64, out: &mut [&mut [i32]]) -> Result<Read> {
        if out.is_empty() || out.len() > self.geometry.channels as usize {
            return Err(Error::InvalidArgument(format!(
                "{} output channels requested; the port has {}",
                out.len(),
                self.geometry.channels
            )));
        }
        let need = (max as u64).min(self.layout.frames_on_port) as usize;
        if let Some((c, s)) = out.iter().enumerate().find(|(_, s)| s.len() < need) {
            return Err(Error::InvalidArgument(format!(
                "output channel {c} holds {} frames, fewer than N = {need}",
                s.len()
            )));
        }
        self.check_size()?;
        let lfi = self.last_frame_index()?;
        let r = self.ring().read(lfi, max, *nfr, out);
        self.check_intact()?;
        *nfr = r.next_frame;
        Ok(Read { frames: r.frames, loss: r.loss })
    }

    /// Like [`Port::get_audio_data`] but leaves the frames in place: returns where they are.
    /// Check [`Port::view_overwritten`] after using them. Advances `*nfr` past the view.
    pub fn view(&self, max: usize, nfr: &mut u64) -> Result<View> {
        self.check_size()?;
        let lfi = self.last_frame_index()?;
        let ring = self.ring();
        let Plan { first, frames, loss } = ring.plan(lfi, max, *nfr);
        self.check_intact()?;
        let nfop = self.layout.frames_on_port;
        let start = format::slot(first, nfop) as usize;
        let len0 = frames.min(nfop as usize - start);
        let segments = [(start, len0), (0, frames - len0)];
        *nfr = first + frames as u64;
        Ok(View { first_frame: first, frames, loss, segments })
    }

    /// How many frames at the start of `view` may have been overwritten since the view was
    /// taken (0 = all of it is intact). Call after processing the frames in place.
    pub fn view_overwritten(&self, view: &View) -> u64 {
        fence(Acquire);
        let intact = self.ring().first_intact(self.header().write_intent.load(Relaxed));
        if self.check_intact().is_err() {
            // The file shrank: what the view showed may have been zero pages.
            return view.frames as u64;
        }
        intact.saturating_sub(view.first_frame).min(view.frames as u64)
    }

    /// Channel `c`'s ring (nFOP samples), for reading a [`View`] in place.
    pub fn channel_ring(&self, c: usize) -> Option<ChannelRing<'_>> {
        (c < self.geometry.channels as usize).then(|| self.ring().channel(c))
    }

    /// Blocks until frame `frame` is published (returns the last frame index), the timeout
    /// expires, the acquisition ends, is replaced, or its writer dies.
    ///
    /// A futex wait on the header's futex word; the writer's liveness is checked at least
    /// every [`LIVENESS_SLICE`] while nothing is published: by its heartbeat while that is
    /// younger than the slice, else of its pidfd (see `reader/liveness.rs`). A writer that
    /// died leaving the port to a successor (`restart_grace_ms`) is waited for meanwhile.
    ///
    /// ```
    /// use std::time::Duration;
    /// use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-wait-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// # let path = dir.join("bass-doc.port");
    /// let geometry = Geometry { channels: 1, sample_rate: 8000, frames_per_chunk: 2, chunks_on_port: 4 };
    /// let mut w = Writer::create_at(&path, &PortParams { geometry, device: "doc".into(), group: None })?;
    /// let port = Port::open_path(&path)?;
    /// let publisher = std::thread::spawn(move || {
    ///     w.publish(Source::Interleaved(&[1, 2]), ChunkMeta::default()).unwrap();
    ///     w
    /// });
    /// assert_eq!(port.wait(2, Duration::from_secs(10))?, 2); // woken by the publish
    /// let w = publisher.join().unwrap();
    /// // Frame 3 does not come: a timeout names the frame and the newest one.
    /// let e = port.wait(3, Duration::from_millis(1)).unwrap_err();
    /// assert!(matches!(e, Error::Timeout { frame: 3, last: 2 }));
    /// w.stop(); // the acquisition ends: waiters are told, not left to time out
    /// assert!(matches!(port.wait(3, Duration::from_secs(10)), Err(Error::Stopped { last: 2 })));
    /// # drop(port);
    /// # w.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn wait(&self, frame: u64, timeout: Duration) -> Result<u64> {
        let timeout_ns = u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX);
        // CLOCK_MONOTONIC deadline (None: never), set on the first pass that would sleep. One
        // clock read per sleep serves the heartbeat, the deadline and the futex timeout; a
        // woken reader returns without reading the clock (every cold page counts here: with
        // many readers on few cores each one's CPU per wake delays all that run after it).
        let mut deadline: Option<Option<u64>> = None;
        let h = self.header();
        let mut check_writer = true;
        loop {
            self.check_size()?;
            let seq = h.futex.load(Acquire);
            let lfi = self.last_frame_index();
            self.check_intact()?;
            let lfi = lfi?;
            if lfi >= frame {
                return Ok(lfi);
            }
            let now = sys::monotonic_ns();
            let (state, beat) = (h.state.load(Acquire), h.heartbeat_mono_ns.load(Relaxed));
            self.check_intact()?;
            // While the writer's heartbeat proves it alive: how long the heartbeat stays fresh.
            let fresh_for = match State::from_u32(state) {
                Some(State::Stopped) => return Err(Error::Stopped { last: lfi }),
                Some(State::Error) => {
                    return Err(Error::Device { code: h.error_code.load(Relaxed), message: self.message() })
                }
                Some(State::Superseded) => return Err(Error::Restarted),
                Some(State::Idle | State::Starting | State::Capturing) => {
                    // A heartbeat (stored at every publish) younger than the liveness slice
                    // shows the writer alive without asking its pidfd.
                    let fresh = (beat <= now)
                        .then(|| LIVENESS_SLICE_NS.saturating_sub(now - beat))
                        .filter(|&ns| ns > 0);
                    if check_writer && fresh.is_none() {
                        self.check_writer_alive()?;
                    }
                    fresh
                }
                None => return Err(Error::Corrupt(format!("state {state}"))),
            };
            let deadline = *deadline.get_or_insert_with(|| now.checked_add(timeout_ns));
            let remaining = deadline.map_or(u64::MAX, |d| d.saturating_sub(now));
            if remaining == 0 {
                if check_writer && fresh_for.is_some() {
                    // The heartbeat spared the check: a writer that died since is still reported.
                    self.check_writer_alive()?;
                }
                return Err(Error::Timeout { frame, last: lfi });
            }
            let nfpc = u64::from(self.geometry.frames_per_chunk.max(1));
            // A frame 31 or more chunks ahead: a far sleep (`sys::FAR_BIT`), bounded by when
            // its chunk is due.
            let (bits, far) =
                sys::wait_bits(frame.saturating_sub(1) / nfpc, lfi / nfpc, self.geometry.chunk_ns());
            let slice = remaining.min(fresh_for.unwrap_or(LIVENESS_SLICE_NS)).min(far.unwrap_or(u64::MAX));
            match sys::futex_wait_bits_until(&h.futex, seq, now.saturating_add(slice), bits) {
                FutexWait::Woken => check_writer = false,
                FutexWait::TimedOut => check_writer = true,
                FutexWait::Interrupted => return Err(Error::Interrupted),
            }
        }
    }
}
