//! serve's port reader: follows one port after another, reads each chunk planar (the port's
//! layout, which is the wire's) into one reused buffer, and hands it to a [`wire::Batch`];
//! full batches go to the sender thread through the bounded queue (see [`super`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{SyncSender, TrySendError};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use bassport::{Error as PortError, Port};

use super::state::{current_state, state_of, Followed};
use super::{Outgoing, CATCH_UP_PATIENCE, STATE_REFRESH};
use crate::net::{BridgeState, SourceState};
use crate::patience::{live_patience_frames, send_or_give_back};
use crate::wire;

/// The iceoryx2 export, if serve offers one.
#[cfg(feature = "iceoryx2")]
pub type Export<'e> = Option<&'e mut crate::iox::Exporter>;
/// The iceoryx2 export: never, in a build without it.
#[cfg(not(feature = "iceoryx2"))]
pub type Export<'e> = Option<&'e mut NoExport>;

/// No iceoryx2 export (a build without the feature).
#[cfg(not(feature = "iceoryx2"))]
pub enum NoExport {}

#[cfg(not(feature = "iceoryx2"))]
impl NoExport {
    fn publish(&mut self, _: &wire::Header, _: &[i32]) {
        match *self {}
    }
}

/// Where a state goes ([`super::state::StatePublisher::publish`]; tests: nowhere).
pub type PublishState<'p> = &'p mut dyn FnMut(&SourceState, bool);

/// The port reader; lives as long as serve, across ports.
pub struct Reader<'a> {
    /// Local broker name (to reopen the port).
    pub name: &'a str,
    /// To the sender thread.
    pub tx: &'a SyncSender<Outgoing>,
    /// SIGTERM/SIGINT.
    pub term: &'a AtomicBool,
    /// Whether a subscriber takes the chunks (see `follow`).
    pub matched: &'a AtomicBool,
    /// This serve's instance id.
    pub instance: u64,
    /// The next chunk's sequence number (across ports).
    pub sequence: u64,
    /// Frames this instance could not send so far.
    pub lost_frames: u64,
    /// The next chunk sent carries SOURCE_LOSS.
    pub pending_loss: bool,
    /// Chunks waiting to go in one message.
    pub batch: wire::Batch,
    /// Chunks of the current port sent / dropped (queue full).
    pub sent: u64,
    /// See `sent`.
    pub dropped: u64,
    /// Whether a chunk of the current port was handed on (sent or dropped): frames that left
    /// the window before that are not the replica's (it starts at the first chunk it gets).
    pub started: bool,
    /// Sending the port's backlog: blocking sends until the reader has caught up.
    pub catching_up: bool,
    /// How far behind the port's newest frame a live chunk may fall while waiting for room
    /// ([`crate::patience::LIVE_PATIENCE`] in the current port's frames).
    pub patience_frames: u64,
    /// The newest frame of the chunks waiting in `batch`.
    batch_last: u64,
    /// The ROS 2 export (`serve --ros2`), if any.
    pub ros2: Option<crate::ros2::Exporter>,
    /// The clock the chunks' stamps are given on: the real one but in the fault build's tests.
    pub clock: crate::fault::SourceClock,
}

/// One port being followed: where the reader is, and its reused buffers.
struct Following {
    port: Followed,
    nfpc: usize,
    nfr: u64,
    /// One chunk, planar: channel 0's frames, then channel 1's, ... (the wire's order).
    planar: Vec<i32>,
    /// The same, interleaved, for the iceoryx2 export only.
    interleaved: Vec<i32>,
}

impl<'a> Reader<'a> {
    /// A reader sending `chunks_per_message` chunks in one message.
    pub fn new(
        name: &'a str,
        tx: &'a SyncSender<Outgoing>,
        term: &'a AtomicBool,
        matched: &'a AtomicBool,
        instance: u64,
        chunks_per_message: u32,
    ) -> Reader<'a> {
        Reader {
            name,
            tx,
            term,
            matched,
            instance,
            sequence: 0,
            lost_frames: 0,
            pending_loss: false,
            batch: wire::Batch::new(chunks_per_message),
            sent: 0,
            dropped: 0,
            started: false,
            catching_up: false,
            patience_frames: 0,
            batch_last: 0,
            ros2: None,
            clock: crate::fault::SourceClock::default(),
        }
    }

    /// Follows one port until it is replaced, its writer dies, or termination.
    pub fn follow(&mut self, port: &Port, publish_state: PublishState, mut iox: Export) -> Result<()> {
        let mut f = self.start(port)?;
        let info_state = port.info().map(|i| BridgeState::of_port(i.state))?;
        publish_state(&state_of(port, &f.port, info_state, self.sent, self.dropped), true);
        let mut last_refresh = Instant::now();
        while !self.term.load(Ordering::Relaxed) {
            match port.wait(f.nfr + f.nfpc as u64 - 1, Duration::from_millis(200)) {
                Ok(_) => {}
                Err(PortError::Timeout { .. }) => {
                    // No chunk for a while: what waits in a batch goes now.
                    self.flush(port)?;
                    self.report(port, &f, publish_state)?;
                    continue;
                }
                Err(PortError::Restarted) => return self.flush(port),
                Err(PortError::Stopped { .. })
                | Err(PortError::Device { .. })
                | Err(PortError::WriterGone { .. }) => {
                    self.flush(port)?;
                    self.report(port, &f, publish_state)?;
                    std::thread::sleep(Duration::from_millis(100));
                    // A new acquisition replaces the file: reopen when the epoch changed.
                    match Port::open(self.name) {
                        Ok(p) if p.info().map(|i| i.epoch != f.port.epoch).unwrap_or(false) => return Ok(()),
                        _ => continue,
                    }
                }
                Err(PortError::Interrupted) => continue,
                Err(e) => return Err(e.into()),
            }
            if !self.started && iox.is_none() && self.ros2.is_none() && !self.matched.load(Ordering::Relaxed)
            {
                // Nobody takes the chunks yet (serve just started, no mirror connected yet):
                // the port is not read, so the first mirror gets it from its oldest frame
                // still in the window rather than a backlog put to nobody.
                std::thread::sleep(Duration::from_millis(20));
            } else {
                self.send_ready(port, &mut f, iox.as_deref_mut())?;
            }
            // The state others see (queryable, liveliness, status) is refreshed at most every
            // STATE_REFRESH while data flows: reading the port's info checks the writer's
            // liveness, and at 750 chunks/s that was most of serve's CPU time.
            if last_refresh.elapsed() >= STATE_REFRESH {
                self.report(port, &f, publish_state)?;
                last_refresh = Instant::now();
            }
        }
        self.flush(port)
    }

    /// Starts on a port: from its oldest frame still in the window (chunk-aligned), as a new
    /// epoch: what the port already holds is sent as a backlog (see [`super`]).
    fn start(&mut self, port: &Port) -> Result<Following> {
        let info = port.info()?;
        let g = info.geometry.clone();
        let nfpc = u64::from(g.frames_per_chunk);
        let oldest = (info.last_frame_index + 1).saturating_sub(info.frames_on_port).max(1);
        let nfr = (oldest - 1).div_ceil(nfpc) * nfpc + 1;
        (self.sent, self.dropped, self.started, self.catching_up) = (0, 0, false, true);
        self.patience_frames = live_patience_frames(g.sample_rate, info.frames_on_port);
        if nfr <= info.last_frame_index {
            tracing::info!(
                epoch = info.epoch,
                first = nfr,
                last = info.last_frame_index,
                "sending the port from its oldest frame (a backlog of {} frames)",
                info.last_frame_index + 1 - nfr
            );
        }
        let samples = nfpc as usize * g.channels as usize;
        Ok(Following {
            port: Followed { epoch: info.epoch, geometry: g },
            nfpc: nfpc as usize,
            nfr,
            planar: vec![0; samples],
            interleaved: Vec::new(),
        })
    }

    /// Publishes the port's current state.
    fn report(&self, port: &Port, f: &Following, publish_state: PublishState) -> Result<()> {
        let st = current_state(port)?;
        publish_state(&state_of(port, &f.port, st, self.sent, self.dropped), false);
        Ok(())
    }

    /// Reads and hands on every whole chunk the port has after `f.nfr`.
    fn send_ready(&mut self, port: &Port, f: &mut Following, mut iox: Export) -> Result<()> {
        let (nfpc, channels) = (f.nfpc as u64, f.port.geometry.channels as usize);
        loop {
            let before = f.nfr;
            let r = {
                let mut outs: [&mut [i32]; wire::MAX_CHANNELS as usize] =
                    std::array::from_fn(|_| Default::default());
                for (o, p) in outs.iter_mut().zip(f.planar.chunks_exact_mut(f.nfpc)) {
                    *o = p;
                }
                port.get_audio_data(f.nfpc, &mut f.nfr, &mut outs[..channels])?
            };
            if r.frames == 0 {
                // Caught up with the port (the backlog, if any, is out): from here on the
                // reader never waits for the network.
                self.catching_up = false;
                return Ok(());
            }
            // Frames that left the window before the first chunk of this port went out are
            // not lost to the replica: it starts at the first chunk it receives.
            if r.loss > 0 && self.started {
                // The port lapped us (we were descheduled): say so in the next message.
                self.lost_frames += r.loss;
                self.pending_loss = true;
                self.sequence += r.loss.div_ceil(nfpc);
            }
            let first = f.nfr - r.frames as u64;
            if r.frames as u64 != nfpc || (first - 1) % nfpc != 0 {
                // A torn chunk (overwritten while copied): count it and realign.
                let next = (f.nfr - 1).div_ceil(nfpc) * nfpc + 1;
                if self.started {
                    self.lost_frames += next - before - r.loss;
                    self.pending_loss = true;
                }
                f.nfr = next;
                continue;
            }
            self.send_chunk(port, f, first, iox.as_deref_mut())?;
        }
    }

    /// Hands on the chunk at `first`, read into `f.planar`.
    fn send_chunk(&mut self, port: &Port, f: &mut Following, first: u64, iox: Export) -> Result<()> {
        let g = &f.port.geometry;
        let ci = port.chunk_info(first).ok();
        let h = wire::Header {
            flags: wire::flags_of_port(ci.map_or(0, |c| c.flags), self.pending_loss),
            instance: self.instance,
            epoch: f.port.epoch,
            sequence: self.sequence,
            first_frame: first,
            frames: g.frames_per_chunk,
            channels: g.channels as u16,
            sample_rate: g.sample_rate,
            chunks_on_port: g.chunks_on_port,
            mono_ns: ci.map_or(0, |c| self.clock.mono(c.mono_ns)),
            realtime_ns: ci.map_or(0, |c| self.clock.realtime(c.realtime_ns, c.mono_ns)),
            send_mono_ns: self.clock.mono(bassport::sys::monotonic_ns()),
            source_lost: self.lost_frames,
            bound_ns: ci.map_or(bassport::format::BOUND_UNKNOWN, |c| c.bound_ns),
            missing_channels: ci.map_or(0, |c| c.missing_channels),
            unaligned_channels: ci.map_or(0, |c| c.unaligned_channels),
            ..Default::default()
        };
        if let Some(x) = iox {
            // The export's own format is interleaved.
            let ch = g.channels as usize;
            f.interleaved.resize(f.planar.len(), 0);
            for (i, s) in f.interleaved.iter_mut().enumerate() {
                *s = f.planar[(i % ch) * f.nfpc + i / ch];
            }
            x.publish(&h, &f.interleaved);
        }
        let last = first + f.nfpc as u64 - 1;
        if let Some(r) = self.ros2.as_mut() {
            r.offer(&h, &f.planar, self.term, may_wait(port, self.catching_up, last, self.patience_frames));
        }
        let gap = h.flags & wire::flags::GAP != 0;
        self.started = true;
        self.batch_last = last;
        if self.batch.push(&h, if gap { &[] } else { &f.planar }) {
            self.flush(port)?;
        }
        self.sequence += 1;
        Ok(())
    }

    /// Hands the waiting chunks to the sender thread. While the queue is full it waits for
    /// room as long as [`may_wait`] says (the live stream: while their newest frame is less
    /// than `patience_frames` behind the port's newest, the port holding the frames
    /// meanwhile; the backlog: up to [`CATCH_UP_PATIENCE`]), never past termination; then
    /// they are dropped, counted.
    pub fn flush(&mut self, port: &Port) -> Result<()> {
        let Some(t) = self.batch.take() else { return Ok(()) };
        let out = Outgoing { sequence: t.first_sequence, bytes: t.bytes };
        let wait = may_wait(port, self.catching_up, self.batch_last, self.patience_frames);
        match send_or_give_back(self.tx, out, self.term, wait) {
            Ok(()) => {
                self.sent += t.chunks;
                self.pending_loss = false;
                Ok(())
            }
            Err(TrySendError::Full(_)) => {
                if self.catching_up && !self.term.load(Ordering::Relaxed) {
                    tracing::warn!(
                        "the network took no chunk for {} ms while sending the port's backlog: \
                         dropping (counted) from here on",
                        CATCH_UP_PATIENCE.as_millis()
                    );
                    self.catching_up = false;
                }
                self.dropped += t.chunks;
                self.lost_frames += t.frames;
                self.pending_loss = true;
                Ok(())
            }
            Err(TrySendError::Disconnected(_)) => Err(anyhow!("the sender thread ended")),
        }
    }
}

/// Whether a chunk whose newest frame is `last` may still wait for room in a full queue: while
/// catching up, for [`CATCH_UP_PATIENCE`] from now; live, while it is less than `patience`
/// frames behind the port's newest frame (read afresh at each try; a port that cannot be read
/// ends the wait).
fn may_wait(port: &Port, catching_up: bool, last: u64, patience: u64) -> impl FnMut() -> bool + '_ {
    let since = Instant::now();
    move || {
        if catching_up {
            since.elapsed() < CATCH_UP_PATIENCE
        } else {
            port.wait(0, Duration::ZERO).is_ok_and(|newest| newest.saturating_sub(last) < patience)
        }
    }
}
