//! One acquisition: the capture thread that reads a device, assembles chunks of
//! nFramesPerChunk frames and publishes them with timestamps; overrun gap filling; the rate
//! estimate; and the handle the control loop keeps (stop, stall watchdog, status).
//!
//! ```text
//!  device reads (any size) ──► chunk assembly ──► Writer::publish (one chunk at a time)
//!        │ Xrun                    ▲ zeros for the frames the overrun lost,
//!        └──► gap = (t_next - t_expected) * rate ┘ so frame index stays proportional to time
//! ```
//!
//! The stall watchdog runs on the control thread, not here: a device read may block inside
//! a plugin (a FIFO, a dead sound server), and the watchdog must fire anyway.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use bassport::format::{chunk_flags, error_code, State};
use bassport::reader::Port;
use bassport::sys::{monotonic_ns, realtime_ns};
use bassport::{ChunkMeta, Geometry, Source, Writer};

use crate::device::sim::LATE_NS;
use crate::device::{Capture, ReadEvent, RecordedChunk, StopSignal};
use basskit::rate_estimator::RateDll;

pub mod multi;
mod timeline;

/// State shared by the capture thread and the control thread.
pub struct Shared {
    writer: Mutex<Writer>,
    stop: StopSignal,
    /// CLOCK_MONOTONIC (ns) of the last data from the device (or of the start).
    progress_ns: AtomicU64,
    /// Set once by whoever ends the acquisition on an error (first one wins).
    ended: AtomicBool,
    /// Whether the device delivered anything yet (the watchdog gives a longer grace before).
    got_data: AtomicBool,
    /// The error that ended the acquisition (code, message), as `fail` recorded it: Status
    /// reports it even when the port it was written into was cut and reads something else.
    failure: Mutex<Option<(u32, String)>>,
}

impl Shared {
    fn new(writer: Writer) -> std::io::Result<Shared> {
        Ok(Shared {
            writer: Mutex::new(writer),
            stop: StopSignal::new()?,
            progress_ns: AtomicU64::new(monotonic_ns()),
            ended: AtomicBool::new(false),
            got_data: AtomicBool::new(false),
            failure: Mutex::new(None),
        })
    }

    fn writer(&self) -> MutexGuard<'_, Writer> {
        self.writer.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Ends the acquisition on an error, once; later calls do nothing.
    /// The source ended by itself: the port shows Stopped with `message` (no error).
    fn end(&self, message: &str) {
        if self.ended.swap(true, Ordering::AcqRel) {
            return;
        }
        tracing::info!("{message}");
        self.writer().set_state(State::Stopped, bassport::format::error_code::NONE, message);
        self.stop.signal();
    }

    fn fail(&self, code: u32, message: &str) -> bool {
        if self.ended.swap(true, Ordering::AcqRel) {
            return false;
        }
        tracing::error!(code, "{message}");
        *self.failure.lock().unwrap_or_else(|e| e.into_inner()) = Some((code, message.to_owned()));
        self.writer().set_state(State::Error, code, message);
        self.stop.signal();
        true
    }
}

/// Parameters of the capture thread.
pub struct CaptureParams {
    /// Port geometry.
    pub geometry: Geometry,
    /// SCHED_FIFO priority (0 = do not ask for real-time scheduling).
    pub rt_priority: i32,
    /// CLOCK_MONOTONIC (ns) at which the Acquire request arrived (for the latency log).
    pub requested_ns: u64,
    /// Stall watchdog threshold in ms (0 = max(4 chunks, 250 ms)).
    pub stall_ms: u64,
    /// A port taken back after a restart: CLOCK_MONOTONIC (ns) at which the frame after its
    /// last one was due. The frames between then and the device's first are published as
    /// GAP, so the frame index stays proportional to time across the restart.
    pub resume_from_ns: Option<u64>,
    /// The master device's channels (the port's first; all of them without followers).
    pub master_channels: u32,
    /// The follower devices ([`multi`]); empty for one device.
    pub followers: Vec<multi::FollowerSpec>,
}

/// A running (or finished) acquisition, as the control thread holds it.
pub struct Acquisition {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
    done: mpsc::Receiver<()>,
    /// Read-only view of the port, for Status.
    pub port: Port,
    /// Device name.
    pub device: String,
    /// Device sample format.
    pub format: String,
    stall_ns: u64,
    grace_ns: u64,
    /// A several-device acquisition's aligner and follower counters.
    multi: Option<Arc<multi::Multi>>,
    followers: Vec<JoinHandle<()>>,
}

/// Warns once per process when real-time scheduling is refused.
static RT_WARNED: AtomicBool = AtomicBool::new(false);

impl Acquisition {
    /// Starts the capture thread on `dev`, publishing into `writer`.
    pub fn start(
        writer: Writer,
        dev: Box<dyn Capture>,
        device: &str,
        p: CaptureParams,
    ) -> std::io::Result<Acquisition> {
        // The broker's own read-only view (Status; the descriptor readers of a memfd port are
        // handed is reopened from it, see crate::handoff).
        let port = match writer.reader_fd().map_err(std::io::Error::other)? {
            Some(fd) => Port::from_fd(fd, &writer.path().display().to_string()),
            None => Port::open_path(writer.path()),
        }
        .map_err(std::io::Error::other)?;
        let g = &p.geometry.clone();
        let period_ns = u64::from(g.frames_per_chunk) * 1_000_000_000 / u64::from(g.sample_rate);
        // A few periods, but never less than 250 ms (scheduling noise on a loaded machine).
        let stall_ns = if p.stall_ms > 0 { p.stall_ms * 1_000_000 } else { (4 * period_ns).max(250_000_000) };
        let grace_ns = stall_ns.max(2_000_000_000);
        let shared = Arc::new(Shared::new(writer)?);
        let format = dev.format_name().to_owned();
        let mut p = p;
        let specs = std::mem::take(&mut p.followers);
        let rt = p.rt_priority;
        let multi = multi::Multi::for_acquisition(device, p.master_channels, &specs, g)?;
        let (tx, done) = mpsc::channel();
        let sh = shared.clone();
        let m = multi.clone();
        let thread = std::thread::Builder::new().name("bassd-capture".into()).spawn(move || {
            let mut dev = dev;
            run(&sh, dev.as_mut(), &p, m);
            drop(dev);
            let _ = tx.send(());
        })?;
        let nfpc = g.frames_per_chunk as usize;
        let followers = multi::spawn_followers(&shared, multi.as_ref(), specs, nfpc, rt)?;
        Ok(Acquisition {
            shared,
            thread: Some(thread),
            done,
            port,
            device: device.into(),
            format,
            stall_ns,
            grace_ns,
            multi,
            followers,
        })
    }

    /// Per device of a several-device acquisition (empty for one device), the master's
    /// overruns and GAP frames being the port's.
    pub fn devices(&self, master_xruns: u64, master_gap_frames: u64) -> Vec<bassport::control::DeviceStatus> {
        self.multi.as_ref().map_or_else(Vec::new, |m| m.status(master_xruns, master_gap_frames))
    }

    /// The stall watchdog: ends the acquisition with DEVICE_STALLED when the device has
    /// delivered nothing for too long. Called periodically by the control loop.
    pub fn check_stall(&self, now_ns: u64) {
        let Some(limit) = self.stall_limit() else { return };
        let idle = now_ns.saturating_sub(self.shared.progress_ns.load(Ordering::Acquire));
        if idle > limit {
            let msg =
                format!("device stalled: no data for {} ms (device {:?})", idle / 1_000_000, self.device);
            self.shared.fail(error_code::DEVICE_STALLED, &msg);
        }
    }

    /// When [`Acquisition::check_stall`] fires if the device delivers nothing more
    /// (CLOCK_MONOTONIC ns), or None when there is nothing to watch: the control loop sleeps
    /// no longer than this, so a stall is reported when due, however long its ticks are.
    pub fn stall_due_ns(&self) -> Option<u64> {
        let limit = self.stall_limit()?;
        // check_stall fires once the silence is longer than the limit.
        Some(self.shared.progress_ns.load(Ordering::Acquire).saturating_add(limit).saturating_add(1))
    }

    /// The silence (ns) the stall watchdog allows now — the stall limit once data came, the
    /// start-up grace before — or None while there is nothing to watch (no capture thread, or
    /// it ended or is stopping).
    fn stall_limit(&self) -> Option<u64> {
        if self.thread.is_none() || self.shared.ended.load(Ordering::Acquire) || self.shared.stop.is_set() {
            return None;
        }
        Some(if self.shared.got_data.load(Ordering::Acquire) { self.stall_ns } else { self.grace_ns })
    }

    /// Stores a heartbeat: the broker is alive even while its device is silent or the
    /// acquisition has ended. Readers in another pid namespace, which cannot look its pid up,
    /// go by it. Called by the control loop at every tick; a publish (which stores one
    /// itself) holding the writer is never made to wait for it.
    pub fn heartbeat(&self) {
        if let Ok(w) = self.shared.writer.try_lock() {
            w.heartbeat();
        }
    }

    /// Restarts the stall watchdog's clock (the broker itself was frozen).
    pub fn rebase_watchdog(&self, now_ns: u64) {
        self.shared.progress_ns.fetch_max(now_ns, Ordering::AcqRel);
    }

    /// Stops the capture: signals the thread, waits up to `timeout` for it, and marks the port
    /// Stopped (unless it already ended on an error). A thread blocked inside the device is
    /// left behind; it exits when the device returns and never publishes again.
    pub fn stop(&mut self, timeout: Duration) {
        self.stop_thread(timeout);
        self.shared.writer().stop();
    }

    /// Stops the capture thread like [`Acquisition::stop`] but leaves the port's state as it
    /// is: an Acquire that replaces this acquisition marks it superseded next, and its readers
    /// see no Stopped in between ([`Acquisition::stop`] if the replacement fails).
    pub fn halt(&mut self, timeout: Duration) {
        self.stop_thread(timeout);
    }

    /// Stops the capture thread like [`Acquisition::stop`] but leaves the port capturing, for
    /// the broker's successor to take back (`Writer::leave_to_successor`).
    pub fn leave_to_successor(&mut self, timeout: Duration) {
        self.stop_thread(timeout);
        self.shared.writer().leave_to_successor();
    }

    /// Whether the capture is in health for the service manager's watchdog: not ended by a
    /// stalled device.
    pub fn healthy(&self) -> bool {
        !matches!(self.failure(), Some((code, _)) if code == error_code::DEVICE_STALLED)
    }

    fn stop_thread(&mut self, timeout: Duration) {
        self.shared.stop.signal();
        if let Some(t) = self.thread.take() {
            match self.done.recv_timeout(timeout) {
                Ok(()) | Err(mpsc::RecvTimeoutError::Disconnected) => {
                    let _ = t.join();
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    tracing::warn!(device = %self.device, "capture thread still blocked in the device after {timeout:?}; leaving it behind");
                }
            }
        }
        multi::join_followers(std::mem::take(&mut self.followers), timeout);
    }

    /// Sets the port's restart grace (0: no successor can take it back, see
    /// `Writer::set_restart_grace_ms`).
    pub fn set_restart_grace_ms(&self, ms: u32) {
        self.shared.writer().set_restart_grace_ms(ms);
    }

    /// Marks the port superseded by a new acquisition and wakes its readers (who then see
    /// `Restarted`). A port file is marked by the new port's commit, which finds it at the
    /// path; a memfd port has no path, so the broker marks it here.
    pub fn supersede(&self) {
        self.shared.writer().set_state(State::Superseded, error_code::NONE, "");
    }

    /// Moves a port that ended on an error to stopped (see `Writer::clear_error`); returns
    /// the error message it cleared.
    pub fn clear_error(&self) -> Option<String> {
        let recorded = self.shared.failure.lock().unwrap_or_else(|e| e.into_inner()).take();
        self.shared.writer().clear_error().or(recorded.map(|(_, m)| m))
    }

    /// The error that ended the acquisition (code, message), until a Stop clears it.
    pub fn failure(&self) -> Option<(u32, String)> {
        self.shared.failure.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Whether the capture thread is still running.
    pub fn running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// The epoch of the acquisition's port.
    pub fn epoch(&self) -> u64 {
        self.port.epoch()
    }
}

/// Chunk assembly state of the capture thread.
struct Assembler<'a> {
    shared: &'a Shared,
    channels: usize,
    nfpc: usize,
    rate: u64,
    chunk: Vec<i32>,
    filled: usize,
    zeros: usize,
    /// Timestamp and "estimated" flag of the chunk's first frame.
    first: Option<(u64, bool)>,
    /// Observed time of the chunk's first frame, when it came from the device.
    observed: Option<u64>,
    discontinuity: bool,
    /// The read that began the chunk came late (a catch-up burst): flag LATE, skip the DLL.
    late: bool,
    /// CLOCK_MONOTONIC (ns) at which the device read that gave the frames being assembled
    /// (or that found the gap being filled) returned: a chunk that reaches the port more than
    /// [`Assembler::late_after_ns`] after it is flagged LATE too, whatever the device said
    /// (the thread was held between its read and the port, see [`chunk_flags::LATE`]).
    read_returned_ns: u64,
    dll: RateDll,
    published: u64,
    requested_ns: u64,
    multi: Option<Arc<multi::Multi>>,
}

impl Assembler<'_> {
    fn frames_ns(&self, frames: u64) -> u64 {
        frames.saturating_mul(1_000_000_000) / self.rate
    }

    /// How long after its newest frames were read a chunk may reach the port without being
    /// LATE: a chunk's duration, at least [`LATE_NS`] (the simulated devices' rule for a
    /// read, so that one definition holds wherever the time is lost).
    fn late_after_ns(&self) -> u64 {
        self.frames_ns(self.nfpc as u64).max(LATE_NS)
    }

    /// The bound of a chunk's stamp `mono` (docs/time.md, "Bounds"): from the rate loop's
    /// prediction once it has settled, else the a-priori bound: one chunk's duration, at
    /// least 1 ms (the first chunks, and every chunk after a gap, whose stamp is extrapolated).
    fn stamp_bound_ns(&self, mono: u64) -> u64 {
        let apriori = self.frames_ns(self.nfpc as u64).max(1_000_000);
        match self.observed {
            Some(_) => self.dll.stamp_bound_ns(mono).unwrap_or(apriori),
            None => apriori,
        }
    }

    /// Appends `n` zero frames whose first one is due at `t_ns`.
    fn push_zeros(&mut self, mut n: u64, mut t_ns: u64) {
        while n > 0 {
            let k = (n as usize).min(self.nfpc - self.filled);
            if self.filled == 0 {
                self.first = Some((t_ns, true));
                self.observed = None;
            }
            self.chunk[self.filled * self.channels..(self.filled + k) * self.channels].fill(0);
            self.filled += k;
            self.zeros += k;
            n -= k as u64;
            t_ns += self.frames_ns(k as u64);
            self.flush_if_full();
        }
    }

    /// Appends frames read from the device (`data` interleaved), the first captured at `t_ns`.
    fn push_frames(&mut self, data: &[i32], t_ns: u64, estimated: bool, observed_ns: u64, late: bool) {
        let mut done = 0;
        let total = data.len() / self.channels;
        while done < total {
            let k = (total - done).min(self.nfpc - self.filled);
            if self.filled == 0 {
                let off = self.frames_ns(done as u64);
                self.first = Some((t_ns + off, estimated));
                self.observed = Some(observed_ns + off);
                self.late = late;
            }
            let dst = &mut self.chunk[self.filled * self.channels..(self.filled + k) * self.channels];
            dst.copy_from_slice(&data[done * self.channels..(done + k) * self.channels]);
            self.filled += k;
            done += k;
            self.flush_if_full();
        }
    }

    fn flush_if_full(&mut self) {
        if self.filled < self.nfpc {
            return;
        }
        let now = monotonic_ns();
        let (mono, estimated) = self.first.unwrap_or((now, true));
        let realtime = realtime_ns().wrapping_add(mono).wrapping_sub(now);
        let mut flags = if estimated { chunk_flags::TIME_ESTIMATED } else { 0 };
        // `late` (the device's word on the read that began the chunk) decides the rate loop's
        // skip; LATE on the port is also a chunk held too long between its read and here.
        let late = std::mem::take(&mut self.late);
        let held_ns = now.saturating_sub(self.read_returned_ns);
        if late || held_ns > self.late_after_ns() {
            flags |= chunk_flags::LATE;
        }
        let all_zero = self.zeros == self.nfpc;
        if all_zero {
            flags |= chunk_flags::GAP;
        } else if self.discontinuity || self.zeros > 0 {
            flags |= chunk_flags::DISCONTINUITY;
            self.discontinuity = false;
        }
        let discontinuity = flags & chunk_flags::DISCONTINUITY != 0;
        let bound_ns = Some(self.stamp_bound_ns(mono));
        let meta = ChunkMeta {
            mono_ns: mono.max(1),
            realtime_ns: realtime.max(1),
            flags,
            bound_ns,
            ..ChunkMeta::default()
        };
        let src = if all_zero { Source::Zeros } else { Source::Interleaved(&self.chunk) };
        if let Some(m) = &self.multi {
            if !self.shared.ended.load(Ordering::Acquire) && !self.shared.stop.is_set() {
                m.master_chunk(self.shared, &self.chunk, all_zero, discontinuity, meta);
            }
        }
        {
            let mut w = self.shared.writer();
            if self.shared.ended.load(Ordering::Acquire) || self.shared.stop.is_set() {
                // Ended by the watchdog or a stop while we were reading: publish nothing more.
                self.filled = 0;
                return;
            }
            let published = if self.multi.is_some() { Ok(0) } else { w.publish(src, meta) };
            if let Err(e) = published {
                drop(w);
                self.shared.fail(error_code::INTERNAL, &format!("publishing a chunk failed: {e}"));
                return;
            }
            if !all_zero && self.zeros > 0 {
                w.add_gap_frames(self.zeros as u64);
            }
            match self.observed {
                // A late chunk's arrival says nothing about the device clock: the loop runs free.
                Some(_) if late && self.zeros == 0 => self.dll.skip(),
                Some(t) if !all_zero && self.zeros == 0 => w.set_rate_estimate(self.dll.update(t)),
                _ => self.dll.reset(),
            }
        }
        self.published += 1;
        if self.published == 1 {
            let ms = monotonic_ns().saturating_sub(self.requested_ns) as f64 / 1e6;
            tracing::info!("first chunk published {ms:.2} ms after the Acquire request");
        }
        self.filled = 0;
        self.zeros = 0;
    }
}

/// Publishing the chunks of a replayed recording as they were recorded (see `device::file`).
struct Replay {
    rate: f64,
    requested_ns: u64,
    published: u64,
    /// The last chunk published was GAP (a GAP run counts as one overrun, as live).
    in_gap: bool,
}

impl Replay {
    /// Moves the port on to `first` (a recorded loss running to the recording's end): its last
    /// frame index to the loss's last whole chunk, and readers count every frame before `first`
    /// lost, as the lost upstream frames do.
    fn skip_to(&mut self, shared: &Shared, first: u64) {
        let mut w = shared.writer();
        if shared.ended.load(Ordering::Acquire) || shared.stop.is_set() {
            return;
        }
        let lfi = w.last_frame_index();
        if first > lfi + 1 {
            match w.skip_to(first) {
                Ok(_) if lfi > 0 => w.add_lost_upstream(first - lfi - 1),
                Ok(_) => {}
                Err(e) => tracing::warn!("replay: skipping the loss at the end to frame {first} failed: {e}"),
            }
        }
    }

    /// Publishes one recorded chunk, first skipping to its readable frame; false once the
    /// acquisition has ended.
    fn publish(&mut self, shared: &Shared, samples: &[i32], c: &RecordedChunk) -> bool {
        let mut w = shared.writer();
        if shared.ended.load(Ordering::Acquire) || shared.stop.is_set() {
            return false;
        }
        let lfi = w.last_frame_index();
        let placed = if c.readable_from > lfi + 1 {
            // The recording's start, or frames its recorder lost: lost for readers here too.
            let skipped = w.skip_to(c.readable_from);
            if lfi > 0 {
                w.add_lost_upstream(c.readable_from - lfi - 1);
            }
            skipped
        } else {
            Ok(lfi)
        };
        match placed {
            Ok(last) if last + 1 == c.first_frame => {}
            other => {
                drop(w);
                let msg = format!(
                    "replay: chunk {} cannot follow frame {lfi} (readable from {}): {other:?}",
                    c.first_frame, c.readable_from
                );
                shared.fail(error_code::INTERNAL, &msg);
                return false;
            }
        }
        let src = if c.zeros { Source::Zeros } else { Source::Interleaved(samples) };
        if let Err(e) = w.publish(src, c.meta) {
            drop(w);
            shared.fail(error_code::INTERNAL, &format!("publishing a chunk failed: {e}"));
            return false;
        }
        if c.zeros && !self.in_gap {
            w.add_xruns(1);
        }
        self.in_gap = c.zeros;
        self.published += 1;
        if self.published == 1 {
            w.set_rate_estimate(self.rate);
            let ms = monotonic_ns().saturating_sub(self.requested_ns) as f64 / 1e6;
            tracing::info!("first chunk published {ms:.2} ms after the Acquire request");
        }
        true
    }
}

/// Asks for SCHED_FIFO at `priority` (0: none); a refusal is said once per process.
fn try_realtime(priority: i32) {
    if priority > 0 {
        if let Err(e) = crate::os::set_realtime(priority) {
            if !RT_WARNED.swap(true, Ordering::Relaxed) {
                tracing::warn!(
                    "real-time scheduling (SCHED_FIFO {priority}) not permitted: {e}; capturing at normal \
                     priority (grant CAP_SYS_NICE or an rtprio limit to enable it)"
                );
            }
        }
    }
}

impl<'a> Assembler<'a> {
    fn new(shared: &'a Shared, p: &CaptureParams, multi: Option<Arc<multi::Multi>>) -> Self {
        let g = &p.geometry;
        let (channels, nfpc) = (p.master_channels as usize, g.frames_per_chunk as usize);
        Assembler {
            shared,
            channels,
            nfpc,
            rate: u64::from(g.sample_rate),
            chunk: vec![0; nfpc * channels],
            filled: 0,
            zeros: 0,
            first: None,
            observed: None,
            discontinuity: false,
            late: false,
            read_returned_ns: 0,
            dll: RateDll::new(f64::from(g.sample_rate), g.frames_per_chunk),
            published: 0,
            requested_ns: p.requested_ns,
            multi,
        }
    }
}

fn run(shared: &Shared, dev: &mut dyn Capture, p: &CaptureParams, multi: Option<Arc<multi::Multi>>) {
    try_realtime(p.rt_priority);
    // No timer slack on this thread: the device pacing's sleeps end when due.
    crate::device::precise_timers();
    if let Err(msg) = dev.start() {
        shared.fail(error_code::DEVICE_LOST, &format!("starting the capture failed: {msg}"));
        return;
    }
    shared.progress_ns.store(monotonic_ns(), Ordering::Release);
    let mut asm = Assembler::new(shared, p, multi);
    let (channels, nfpc) = (asm.channels, asm.nfpc);
    let mut scratch = vec![0i32; nfpc * channels];
    let rate = f64::from(p.geometry.sample_rate);
    let mut replay = Replay { rate, requested_ns: p.requested_ns, published: 0, in_gap: false };
    let mut timeline = timeline::Timeline::new(p, &asm);
    while !shared.stop.is_set() {
        let want = nfpc - asm.filled;
        match dev.read(&mut scratch, want, &shared.stop) {
            ReadEvent::Frames { frames, first_mono_ns, time_estimated, observed_mono_ns, late } => {
                asm.read_returned_ns = monotonic_ns();
                shared.progress_ns.store(asm.read_returned_ns, Ordering::Release);
                shared.got_data.store(true, Ordering::Release);
                timeline.before_frames(&mut asm, first_mono_ns, frames);
                let samples = &scratch[..frames * channels];
                asm.push_frames(samples, first_mono_ns, time_estimated, observed_mono_ns, late);
            }
            ReadEvent::Xrun => {
                shared.writer().add_xruns(1);
                timeline.after_xrun = true;
            }
            ReadEvent::Chunk(c) => {
                shared.progress_ns.store(monotonic_ns(), Ordering::Release);
                shared.got_data.store(true, Ordering::Release);
                if !replay.publish(shared, &scratch[..nfpc * channels], &c) {
                    break;
                }
            }
            ReadEvent::Idle => {}
            ReadEvent::Pending => shared.progress_ns.store(monotonic_ns(), Ordering::Release),
            ReadEvent::Stopped => break,
            ReadEvent::Failed { code, message } => {
                shared.fail(code, &message);
                break;
            }
            ReadEvent::Ended { message, lost_to } => {
                if let Some(f) = lost_to {
                    replay.skip_to(shared, f);
                }
                shared.end(&message);
                break;
            }
        }
        if shared.ended.load(Ordering::Acquire) {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bassport::PortParams;

    /// A capture thread held between a device read and the port (preempted, or waiting for
    /// a CPU the host did not run: bench/analysis.md, "The tail on a shared host", traced one
    /// held 5.2 ms after a read that came on time) publishes a chunk late: LATE says so, as
    /// format.rs defines it, though the device's read was not late.
    #[test]
    fn a_chunk_held_between_its_read_and_the_port_is_flagged_late() {
        let dir = std::env::temp_dir().join(format!("bass-capture-late-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join("port");
        let geometry =
            Geometry { channels: 2, sample_rate: 48_000, frames_per_chunk: 48, chunks_on_port: 16 };
        let params = PortParams { geometry: geometry.clone(), device: "test".into(), group: None };
        let writer = Writer::create_at(&path, &params).expect("create the port");
        let port = Port::open_path(&path).expect("open the port");
        let shared = Shared::new(writer).expect("the capture's shared state");
        let p = CaptureParams {
            geometry,
            rt_priority: 0,
            requested_ns: monotonic_ns(),
            stall_ms: 0,
            resume_from_ns: None,
            master_channels: 2,
            followers: Vec::new(),
        };
        let mut asm = Assembler::new(&shared, &p, None);
        let frames = vec![7i32; 48 * 2];
        // Three reads of a chunk each, on time by the device's word; the second one's chunk
        // waits 5 ms (five times the 1 ms bound) between the read and the port.
        for hold_ms in [0u64, 5, 0] {
            let t = monotonic_ns();
            asm.read_returned_ns = t;
            std::thread::sleep(Duration::from_millis(hold_ms));
            asm.push_frames(&frames, t, false, t, false);
        }
        let flags: Vec<bool> = [1u64, 49, 97]
            .iter()
            .map(|&f| port.chunk_info(f).expect("chunk info").flags & chunk_flags::LATE != 0)
            .collect();
        drop(asm);
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(flags, [false, true, false], "LATE on chunks 1..3 (the second held 5 ms)");
    }
}
