//! Callback streams: the wait/read loop every client writes, written once, with what only
//! bass can tell a callback — the absolute index of a block's first frame, the exact number
//! of frames lost before it, its chunk flags and capture timestamps.
//!
//! A [`Stream`] reads a [`Port`] in blocks of `frames_per_call` frames and hands each to a
//! closure as a [`Block`]; the blocks tile the stream: `block.first_frame` is the previous
//! block's end plus `block.lost`. Events ([`Event`]: stopped, restarted, device error,
//! writer gone) go to a second closure. It runs on the caller's thread ([`Stream::run`]) or
//! on a thread of its own ([`Stream::spawn`]), optionally `SCHED_FIFO`.
//!
//! Realtime rules of the steady path (a block is due): every buffer is allocated when the
//! stream is built; a block costs atomic loads, copies out of the mapping and the futex
//! wait — no allocation, no lock, no other system call (tests/stream_rt.rs counts the
//! allocations). Exceptions, off the audio path: a restart reopens the port (allocates, opens
//! files); while the writer is silent for more than [`crate::reader::LIVENESS_SLICE`] its
//! liveness is asked of a pidfd (a lock and a `poll`; /proc once per writer); with the SIGBUS guard off (`BASS_SIGBUS_GUARD=0`) every read
//! of a port *file* checks its size (one `lseek`).
//!
//! ```
//! use bassport::stream::{Config, Control, Stream};
//! use bassport::{ChunkMeta, Geometry, PortParams, Source, Writer};
//! # let dir = std::env::temp_dir().join(format!("bass-doc-stream-{}", std::process::id()));
//! # std::fs::create_dir_all(&dir).unwrap();
//! # let path = dir.join("bass-doc.port");
//! let geometry = Geometry { channels: 2, sample_rate: 8000, frames_per_chunk: 2, chunks_on_port: 4 };
//! let mut w = Writer::create_at(&path, &PortParams { geometry, device: "doc".into(), group: None })?;
//! w.publish(Source::Interleaved(&[1, -1, 2, -2]), ChunkMeta::default())?;
//! w.publish(Source::Interleaved(&[3, -3, 4, -4]), ChunkMeta::default())?;
//! w.stop();
//! let mut stream = Stream::open_path(&path, Config::default().oldest())?;
//! let mut seen = Vec::new();
//! stream.run(
//!     |b| {
//!         seen.push((b.first_frame, b.lost, b.channel(0).unwrap().to_vec(), b.channel(1).unwrap().to_vec()));
//!         Control::Continue
//!     },
//!     |_event| Control::Stop, // stopped: end the stream
//! )?;
//! assert_eq!(seen, [(1, 0, vec![1, 2], vec![-1, -2]), (3, 0, vec![3, 4], vec![-3, -4])]);
//! # w.remove()?;
//! # std::fs::remove_dir_all(&dir).ok();
//! # Ok::<(), bassport::Error>(())
//! ```

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::error::{Error, Result};
use crate::format::{self, State};
use crate::reader::{ChunkInfo, Port, LIVENESS_SLICE};
use crate::sys::{self, FutexWait};

mod thread;
mod types;

pub use thread::StreamHandle;
pub use types::{Block, Config, Control, Event, SampleLayout, Start, Stopper};

/// Longest futex wait between two looks at the stop flag while no block is due.
pub const STOP_SLICE: Duration = Duration::from_millis(50);
/// How long a restart waits for the new acquisition's port to appear.
pub const REOPEN_TIMEOUT: Duration = Duration::from_secs(5);

/// How the stream finds a port again after a restart.
#[derive(Clone, Debug)]
enum Reopen {
    Name(String),
    Path(PathBuf),
}

impl Reopen {
    fn open(&self) -> Result<Port> {
        match self {
            Reopen::Name(n) => Port::open(n),
            Reopen::Path(p) => Port::open_path(p),
        }
    }
}

/// Why a wait ended without the frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum End {
    Stopped {
        last: u64,
    },
    Device {
        code: u32,
    },
    WriterGone {
        pid: u32,
    },
    Superseded,
    /// After an end the stream outlived: the same acquisition goes on (a live writer, the
    /// port capturing again: a broker that took the port back, a frozen writer awake again).
    Resumed,
    StopAsked,
}

/// A callback stream over one port (see the module's documentation).
pub struct Stream {
    port: Arc<Port>,
    reopen: Reopen,
    cfg: Config,
    channels: Vec<u32>,
    frames: usize,
    planar: Vec<Vec<i32>>,
    interleaved: Vec<i32>,
    chunks: Vec<Option<ChunkInfo>>,
    message: [u8; format::MESSAGE_LEN],
    stop: Stopper,
    nfr: Option<u64>,
    pending_loss: u64,
}

impl Stream {
    /// A stream over the port `name` (reopened by name after a restart).
    pub fn open(name: &str, cfg: Config) -> Result<Stream> {
        Stream::build(Arc::new(Port::open(name)?), Reopen::Name(name.to_owned()), cfg)
    }

    /// A stream over the port file at `path` (reopened by path after a restart).
    pub fn open_path(path: &Path, cfg: Config) -> Result<Stream> {
        Stream::build(Arc::new(Port::open_path(path)?), Reopen::Path(path.to_owned()), cfg)
    }

    /// A stream over an open port, reopened after a restart by its name when its path is the
    /// runtime directory's `bass-NAME.port` (so that a broker's memfd port is found again),
    /// else by its path.
    pub fn new(port: Arc<Port>, cfg: Config) -> Result<Stream> {
        let name = port
            .path()
            .file_name()
            .and_then(|f| f.to_str())
            .and_then(|f| f.strip_prefix("bass-"))
            .and_then(|f| f.strip_suffix(".port"))
            .filter(|n| crate::paths::port_path(n).is_ok_and(|p| p == port.path()));
        let reopen = match name {
            Some(n) => Reopen::Name(n.to_owned()),
            None => Reopen::Path(port.path().to_owned()),
        };
        Stream::build(port, reopen, cfg)
    }

    fn build(port: Arc<Port>, reopen: Reopen, cfg: Config) -> Result<Stream> {
        let mut s = Stream {
            port,
            reopen,
            cfg,
            channels: Vec::new(),
            frames: 0,
            planar: Vec::new(),
            interleaved: Vec::new(),
            chunks: Vec::new(),
            message: [0; format::MESSAGE_LEN],
            stop: Stopper(Arc::new(AtomicBool::new(false))),
            nfr: None,
            pending_loss: 0,
        };
        s.allocate()?;
        Ok(s)
    }

    /// Checks the configuration against the port and allocates every buffer of the steady path.
    fn allocate(&mut self) -> Result<()> {
        let g = self.port.geometry();
        let frames = if self.cfg.frames_per_call == 0 {
            g.frames_per_chunk as usize
        } else {
            self.cfg.frames_per_call
        };
        if frames as u64 > self.port.frames_on_port() {
            return Err(Error::InvalidArgument(format!(
                "frames_per_call = {frames} exceeds the port's window of {} frames",
                self.port.frames_on_port()
            )));
        }
        let channels: Vec<u32> =
            if self.cfg.channels.is_empty() { (0..g.channels).collect() } else { self.cfg.channels.clone() };
        if let Some(c) = channels.iter().find(|&&c| c >= g.channels) {
            return Err(Error::InvalidArgument(format!(
                "channel {c} requested; the port has {}",
                g.channels
            )));
        }
        if channels.len() > format::MAX_CHANNELS as usize {
            return Err(Error::InvalidArgument(format!(
                "{} channels requested (at most 64)",
                channels.len()
            )));
        }
        let nfpc = g.frames_per_chunk as usize;
        self.planar = vec![vec![0; frames]; channels.len()];
        self.interleaved = match self.cfg.layout {
            SampleLayout::Interleaved => vec![0; frames * channels.len()],
            SampleLayout::Planar => Vec::new(),
        };
        // A block of `frames` frames touches at most frames / nFPC + 2 chunks.
        self.chunks = vec![None; frames / nfpc + 2];
        self.channels = channels;
        self.frames = frames;
        Ok(())
    }

    /// A handle that stops this stream from any thread.
    pub fn stopper(&self) -> Stopper {
        self.stop.clone()
    }

    /// The port being read (it changes at a restart).
    pub fn port(&self) -> &Arc<Port> {
        &self.port
    }

    /// Frames per block.
    pub fn frames_per_call(&self) -> usize {
        self.frames
    }

    /// The port channels delivered, in order.
    pub fn channels(&self) -> &[u32] {
        &self.channels
    }

    /// The next frame the stream reads (None before it has run).
    pub fn next_frame(&self) -> Option<u64> {
        self.nfr
    }

    /// Runs the stream on the calling thread until a callback returns [`Control::Stop`],
    /// [`Stopper::stop`] is called, or an error that is no acquisition event (a corrupt port,
    /// a failed reopen) ends it. A stream that returned may be run again: it goes on where it
    /// stopped (a stop asked before is forgotten). With a realtime priority, the thread runs
    /// `SCHED_FIFO` during the run and gets its own scheduling back when `run` returns (a
    /// refusal is reported by [`Event::RealtimeRefused`] at every run it happens in).
    pub fn run<B, E>(&mut self, mut on_block: B, mut on_event: E) -> Result<()>
    where
        B: FnMut(&Block<'_>) -> Control,
        E: FnMut(&Event<'_>) -> Control,
    {
        // Put back when the run ends, also by a callback's panic.
        let mut restore = sys::sched::Restore(None);
        if let Some(p) = self.cfg.realtime_priority {
            let before = sys::sched::Sched::current();
            match sys::sched::set_fifo(p) {
                Ok(()) => restore.0 = before,
                Err(errno) => {
                    if on_event(&Event::RealtimeRefused { errno }) == Control::Stop {
                        return Ok(());
                    }
                }
            }
        }
        let mut nfr = match self.nfr {
            Some(n) => n,
            None => self.start_frame(self.cfg.start),
        };
        let result = self.run_from(&mut nfr, &mut on_block, &mut on_event);
        self.nfr = Some(nfr);
        self.stop.0.store(false, Ordering::Release);
        drop(restore);
        result
    }

    fn run_from<B, E>(&mut self, nfr: &mut u64, on_block: &mut B, on_event: &mut E) -> Result<()>
    where
        B: FnMut(&Block<'_>) -> Control,
        E: FnMut(&Event<'_>) -> Control,
    {
        // After an end the caller chose to outlive (its last frame): only a resume
        // of the same acquisition, a new one (superseded) or a stop is awaited.
        let mut ended: Option<u64> = None;
        loop {
            let target = nfr.saturating_add(self.frames as u64 - 1);
            let end = match self.wait_for(target, ended)? {
                None => {
                    if self.deliver(nfr, on_block)? == Control::Stop {
                        return Ok(());
                    }
                    continue;
                }
                Some(end) => end,
            };
            if end == End::StopAsked {
                return Ok(());
            }
            // The frames before the end, fewer than a block (once per end).
            if ended.is_none() && end != End::Resumed && self.deliver(nfr, on_block)? == Control::Stop {
                return Ok(());
            }
            let control = match end {
                End::Stopped { last } => on_event(&Event::Stopped { last }),
                End::Device { code } => {
                    let message = self.read_message();
                    on_event(&Event::Device { code, message })
                }
                End::WriterGone { pid } => on_event(&Event::WriterGone { pid }),
                End::Resumed => {
                    // The frames missed meanwhile are the next block's `lost` (gone from the
                    // window) or GAP frames the successor published.
                    ended = None;
                    if on_event(&Event::Resumed { epoch: self.port.epoch(), resume_at: *nfr })
                        == Control::Stop
                    {
                        return Ok(());
                    }
                    continue;
                }
                End::Superseded => match self.reopen_port()? {
                    None => return Ok(()),
                    Some((epoch, resume_at)) => {
                        *nfr = resume_at;
                        ended = None;
                        if on_event(&Event::Restarted { epoch, resume_at }) == Control::Stop {
                            return Ok(());
                        }
                        continue;
                    }
                },
                End::StopAsked => return Ok(()),
            };
            if control == Control::Stop {
                return Ok(());
            }
            // Every frame up to the end was delivered: frames after it mean the acquisition
            // went on (whatever the callback did meanwhile).
            ended = Some(nfr.saturating_sub(1));
        }
    }

    fn start_frame(&self, start: Start) -> u64 {
        let lfi = self.port.stream_header().last_frame_index.load(Ordering::Acquire);
        match start {
            Start::Oldest => (lfi + 1).saturating_sub(self.port.frames_on_port()).max(1),
            Start::Now => lfi + 1,
            Start::Frame(f) => f.max(1),
        }
    }

    /// Waits until frame `target` is published (None) or the acquisition ends. With `ended`
    /// (the last frame of the acquisition that ended), only a resume of the acquisition, a new one or a
    /// stop ends the wait. Atomic loads and
    /// the futex wait; the writer's liveness is asked (a pidfd) only while its heartbeat is
    /// older than the liveness slice, and a dead writer's broker only while it stays dead.
    fn wait_for(&self, target: u64, ended: Option<u64>) -> Result<Option<End>> {
        let port = &*self.port;
        let h = port.stream_header();
        let nfpc = u64::from(port.geometry().frames_per_chunk.max(1));
        let (target_chunk, chunk_ns) = (target.saturating_sub(1) / nfpc, port.geometry().chunk_ns());
        let stop_slice_ns = STOP_SLICE.as_nanos() as u64;
        loop {
            if self.stop.is_stopped() {
                return Ok(Some(End::StopAsked));
            }
            port.stream_check()?;
            let seq = h.futex.load(Ordering::Acquire);
            let lfi = h.last_frame_index.load(Ordering::Acquire);
            if lfi > format::MAX_FRAME_INDEX {
                return Err(Error::Corrupt(format!("last frame index {lfi} is beyond the format's limit")));
            }
            if lfi >= target && ended.is_none() {
                return Ok(None);
            }
            let state = h.state.load(Ordering::Acquire);
            let now = sys::monotonic_ns();
            let live =
                matches!(State::from_u32(state), Some(State::Idle | State::Starting | State::Capturing));
            match State::from_u32(state) {
                Some(State::Superseded) => return Ok(Some(End::Superseded)),
                _ if ended.is_some() => {
                    // Ended by a stop, an error or a dead writer: the acquisition goes on once
                    // frames follow the end, or its port is live again under a live writer; a
                    // dead one's broker may have started another (a memfd port nobody marks
                    // superseded).
                    if ended.is_some_and(|at| lfi > at) {
                        return Ok(Some(End::Resumed));
                    }
                    if port.writer_alive(|| now) {
                        if live {
                            return Ok(Some(End::Resumed));
                        }
                    } else if port.replaced_by_successor() {
                        return Ok(Some(End::Superseded));
                    }
                }
                Some(State::Stopped) => return Ok(Some(End::Stopped { last: lfi })),
                Some(State::Error) => {
                    return Ok(Some(End::Device { code: h.error_code.load(Ordering::Relaxed) }))
                }
                Some(State::Idle | State::Starting | State::Capturing) => {
                    let beat = h.heartbeat_mono_ns.load(Ordering::Relaxed);
                    if now.saturating_sub(beat) >= LIVENESS_SLICE.as_nanos() as u64
                        && !port.writer_alive(|| now)
                    {
                        if port.replaced_by_successor() {
                            return Ok(Some(End::Superseded));
                        }
                        if let Some(pid) = port.writer_gone(now) {
                            return Ok(Some(End::WriterGone { pid }));
                        }
                    }
                }
                None => return Err(Error::Corrupt(format!("state {state}"))),
            }
            // A target 31 or more chunks ahead: a far sleep (`sys::FAR_BIT`), bounded by when
            // its chunk is due.
            let (bits, far) = sys::wait_bits(target_chunk, lfi / nfpc, chunk_ns);
            let slice_ns = stop_slice_ns.min(far.unwrap_or(u64::MAX));
            match sys::futex_wait_bits_until(&h.futex, seq, now.saturating_add(slice_ns), bits) {
                FutexWait::Woken | FutexWait::TimedOut | FutexWait::Interrupted => {}
            }
        }
    }

    /// The writer's message, copied into the stream's own buffer (no allocation).
    fn read_message(&mut self) -> &str {
        let h = self.port.stream_header();
        for (dst, w) in self.message.chunks_exact_mut(8).zip(h.message.iter()) {
            dst.copy_from_slice(&w.load(Ordering::Relaxed).to_le_bytes());
        }
        let end = self.message.iter().position(|&b| b == 0).unwrap_or(self.message.len());
        match std::str::from_utf8(&self.message[..end]) {
            Ok(s) => s,
            Err(e) => std::str::from_utf8(&self.message[..e.valid_up_to()]).unwrap_or(""),
        }
    }

    /// Reads up to one block from `*nfr` and hands it to `on_block` (nothing when no frame
    /// is there, or every frame read was overwritten meanwhile: then its loss is carried to
    /// the next block).
    fn deliver<B>(&mut self, nfr: &mut u64, on_block: &mut B) -> Result<Control>
    where
        B: FnMut(&Block<'_>) -> Control,
    {
        let port = &*self.port;
        let view = port.view(self.frames, nfr)?;
        if view.frames == 0 {
            self.pending_loss += view.loss;
            return Ok(Control::Continue);
        }
        for (k, &c) in self.channels.iter().enumerate() {
            let Some(ring) = port.channel_ring(c as usize) else { continue };
            let dst = &mut self.planar[k];
            let mut at = 0;
            for &(start, len) in &view.segments {
                if len > 0 {
                    ring.copy_to(start, &mut dst[at..at + len]);
                }
                at += len;
            }
        }
        let nfpc = u64::from(port.geometry().frames_per_chunk);
        let first_chunk = (view.first_frame - 1) / nfpc;
        let last_chunk = (view.first_frame + view.frames as u64 - 2) / nfpc;
        for (slot, chunk) in self.chunks.iter_mut().zip(first_chunk..=last_chunk) {
            *slot = port.chunk_info((chunk * nfpc + 1).max(view.first_frame)).ok();
        }
        // Frames the writer may have overwritten while they were copied are lost.
        let overwritten = port.view_overwritten(&view) as usize;
        let lost = self.pending_loss + view.loss + overwritten as u64;
        let frames = view.frames - overwritten;
        if frames == 0 {
            self.pending_loss = lost;
            return Ok(Control::Continue);
        }
        self.pending_loss = 0;
        let first = view.first_frame + overwritten as u64;
        let (from, to) = (((first - 1) / nfpc - first_chunk) as usize, (last_chunk - first_chunk) as usize);
        let covered = &self.chunks[from..=to];
        let flags = covered.iter().flatten().fold(0, |f, c| f | c.flags);
        let h = port.stream_header();
        let estimate = h.rate_estimate_mhz.load(Ordering::Relaxed) as f64 / 1000.0;
        let rate_hz = if estimate > 0.0 { estimate } else { f64::from(port.geometry().sample_rate) };
        let (mono_ns, realtime_ns) = match covered.first().copied().flatten() {
            Some(c) => {
                let offset = ((first - c.first_frame) as f64 * 1e9 / rate_hz) as u64;
                (c.mono_ns.saturating_add(offset), c.realtime_ns.saturating_add(offset))
            }
            None => (0, 0),
        };
        if self.cfg.layout == SampleLayout::Interleaved {
            let n = self.channels.len();
            for (k, buf) in self.planar.iter().enumerate() {
                for (i, &s) in buf[overwritten..overwritten + frames].iter().enumerate() {
                    self.interleaved[i * n + k] = s;
                }
            }
        }
        let block = Block {
            epoch: port.epoch(),
            first_frame: first,
            frames,
            lost,
            flags,
            mono_ns,
            realtime_ns,
            rate_hz,
            channels: &self.channels,
            planar: &self.planar,
            interleaved: &self.interleaved,
            offset: overwritten,
            layout: self.cfg.layout,
        };
        // The next frame is known before the callback runs: a run after a panic in it goes
        // on after this block instead of delivering it again.
        self.nfr = Some(*nfr);
        let control = on_block(&block);
        Ok(if self.stop.is_stopped() { Control::Stop } else { control })
    }

    /// After the port was superseded: opens the new acquisition's port (retrying while it is
    /// not there yet) and reallocates the buffers for its geometry. Returns its epoch and the
    /// frame the stream resumes at (its oldest), or None when a stop was asked meanwhile.
    fn reopen_port(&mut self) -> Result<Option<(u64, u64)>> {
        let old = self.port.epoch();
        let deadline = Instant::now() + REOPEN_TIMEOUT;
        let port = loop {
            if self.stop.is_stopped() {
                return Ok(None);
            }
            match self.reopen.open() {
                Ok(p) if p.epoch() != old => break p,
                Ok(_) | Err(Error::NotFound { .. } | Error::NotReady) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(5));
                }
                Ok(_) => {
                    return Err(Error::Corrupt(format!(
                    "the port was superseded, but no new acquisition replaced it within {REOPEN_TIMEOUT:?}"
                )))
                }
                Err(e) => return Err(e),
            }
        };
        self.port = Arc::new(port);
        self.allocate()?;
        self.pending_loss = 0;
        Ok(Some((self.port.epoch(), self.start_frame(Start::Oldest))))
    }

    /// Runs the stream on a thread of its own (named `bass-stream`; `SCHED_FIFO` if the
    /// configuration asks). The handle stops it and joins the thread, also when dropped.
    pub fn spawn<B, E>(mut self, on_block: B, on_event: E) -> Result<StreamHandle>
    where
        B: FnMut(&Block<'_>) -> Control + Send + 'static,
        E: FnMut(&Event<'_>) -> Control + Send + 'static,
    {
        let stopper = self.stopper();
        let thread = std::thread::Builder::new()
            .name("bass-stream".into())
            .spawn(move || {
                let r = self.run(on_block, on_event);
                (self, r)
            })
            .map_err(|e| Error::io("spawn the stream thread", e))?;
        Ok(StreamHandle { stopper, thread: Some(thread) })
    }
}
