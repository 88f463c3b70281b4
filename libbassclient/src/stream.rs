//! C ABI of the callback stream ([`bassport::stream`]): `bass_stream_start` (bass's own thread),
//! `bass_stream_create` + `bass_stream_run` (the caller's thread), `bass_stream_stop` (any
//! thread, also inside a callback) and `bass_stream_close`. Conventions in [`super`].

use std::ffi::{c_char, c_int, c_void};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::ThreadId;

use super::{bass_port, bass_result, boundary, nonnull, nonnull_mut, put, Failure, Registry};
use bassport::error::Error;
use bassport::format::MESSAGE_LEN;
use bassport::stream::{Block, Config, Control, Event, SampleLayout, Start, Stopper, Stream, StreamHandle};

/// Start at the oldest frame in the window.
pub const BASS_START_OLDEST: u32 = 0;
/// Start at the next frame to be published (the live edge).
pub const BASS_START_NOW: u32 = 1;
/// Start at `bass_stream_config.start_frame`.
pub const BASS_START_FRAME: u32 = 2;
/// Event: the acquisition stopped; `frame` is its last frame.
pub const BASS_EVENT_STOPPED: u32 = 1;
/// Event: a new acquisition replaced the port; `epoch` is its epoch, `frame` where the
/// stream resumes (its oldest frame).
pub const BASS_EVENT_RESTARTED: u32 = 2;
/// Event: the acquisition ended on a device error; `code` (`BASS_DEVERR_*`) and `message`.
pub const BASS_EVENT_DEVICE: u32 = 3;
/// Event: the writer (broker) process is gone; `code` is its pid.
pub const BASS_EVENT_WRITER_GONE: u32 = 4;
/// Event: SCHED_FIFO was refused (`os_error` is the errno); the stream runs unprioritised.
pub const BASS_EVENT_REALTIME_REFUSED: u32 = 5;
/// Event: after `BASS_EVENT_STOPPED`, `_DEVICE` or `_WRITER_GONE`, the same acquisition goes
/// on (same port, same `epoch`: a restarted broker took the port back, or the writer is alive
/// again); `frame` is the next frame the stream reads. Frames that left the window meanwhile
/// are the next block's `lost`; the frames the writer missed come as `BASS_CHUNK_GAP` zeros.
pub const BASS_EVENT_RESUMED: u32 = 6;

/// What a callback stream delivers. Zero-initialised: one chunk per call, from the oldest
/// frame, every channel, planar, no realtime priority.
#[repr(C)]
pub struct bass_stream_config {
    /// Frames per call (0: one chunk); at most the port's window.
    pub frames_per_call: usize,
    /// `BASS_START_*`.
    pub start: u32,
    /// 1: interleaved samples (`bass_block.interleaved`); 0: planar (`bass_block.channels`).
    pub interleaved: u32,
    /// The first frame when `start` is `BASS_START_FRAME`.
    pub start_frame: u64,
    /// The port channels wanted, in order (nullable: every channel).
    pub channels: *const u32,
    /// Entries of `channels`.
    pub n_channels: usize,
    /// SCHED_FIFO priority of the thread running the stream (0: none).
    pub realtime_priority: i32,
}

/// One block, valid during the block callback only.
#[repr(C)]
pub struct bass_block {
    /// Acquisition epoch of the frames.
    pub epoch: u64,
    /// Absolute index of the first frame.
    pub first_frame: u64,
    /// Frames in the block.
    pub frames: usize,
    /// Frames lost between the previous block (or the start) and this one.
    pub lost: u64,
    /// CLOCK_MONOTONIC (ns) of the first frame.
    pub mono_ns: u64,
    /// CLOCK_REALTIME (ns) of the first frame.
    pub realtime_ns: u64,
    /// The writer's device-rate estimate in Hz (the nominal rate until there is one).
    pub rate_hz: f64,
    /// `BASS_CHUNK_*` flags OR-ed over the chunks the block covers.
    pub flags: u32,
    /// Channels in the block.
    pub n_channels: u32,
    /// The port channel of each of the block's channels.
    pub port_channels: *const u32,
    /// Planar: `n_channels` pointers to `frames` samples each (NULL when interleaved).
    pub channels: *const *const i32,
    /// Interleaved: `frames * n_channels` samples (NULL when planar).
    pub interleaved: *const i32,
}

/// An acquisition event, valid during the event callback only.
#[repr(C)]
pub struct bass_stream_event {
    /// `BASS_EVENT_*`.
    pub kind: u32,
    /// `BASS_DEVERR_*` (device), the writer's pid (writer gone), else 0.
    pub code: u32,
    /// The epoch (restarted: the new one), else the stream's current epoch.
    pub epoch: u64,
    /// The last frame (stopped), the frame the stream resumes at (restarted, resumed), else 0.
    pub frame: u64,
    /// The errno (realtime refused), else 0.
    pub os_error: c_int,
    /// The writer's message (device), else "" (never NULL).
    pub message: *const c_char,
}

/// Receives one block; returns 0 to go on, anything else to stop the stream.
pub type bass_block_fn = Option<unsafe extern "C" fn(block: *const bass_block, user: *mut c_void) -> c_int>;
/// Receives an event; returns 0 to go on (after stopped, device or writer gone: wait for a new
/// acquisition), anything else to stop the stream.
pub type bass_event_fn =
    Option<unsafe extern "C" fn(event: *const bass_stream_event, user: *mut c_void) -> c_int>;

/// Opaque handle of a callback stream.
pub struct bass_stream {
    _private: [u8; 0],
}

/// The user's pointer, handed back to the callbacks on the stream's thread.
#[derive(Clone, Copy)]
struct User(*mut c_void);
// SAFETY: the pointer is only passed back to the caller's callbacks; the caller's contract
// (docs/c-api.md) makes it valid on the stream's thread.
unsafe impl Send for User {}
// SAFETY: bass never dereferences it; it is only copied into the callbacks' calls.
unsafe impl Sync for User {}

/// The planar channel pointers of the block being delivered (owned by the stream's thread).
struct Pointers(Vec<*const i32>);
// SAFETY: the pointers are written and read only on the thread running the stream, and only
// during a block callback (they point into the stream's own buffers).
unsafe impl Send for Pointers {}

impl Pointers {
    /// The vector (a method, so that a closure captures the whole `Send` wrapper).
    fn vec(&mut self) -> &mut Vec<*const i32> {
        &mut self.0
    }
}

struct CStream {
    stopper: Stopper,
    /// The stream while it is not running on bass's thread (create, then run).
    idle: Mutex<Option<Stream>>,
    handle: Mutex<Option<StreamHandle>>,
    /// The thread inside `bass_stream_run` (None: none), and its end's signal for `close`.
    runner: Mutex<Option<ThreadId>>,
    run_ended: Condvar,
    callbacks: (bass_block_fn, bass_event_fn, User),
}

impl CStream {
    /// The thread running the stream's callbacks now (bass's or a caller's), if any.
    fn running_thread(&self) -> Option<ThreadId> {
        let own =
            self.handle.lock().unwrap_or_else(|e| e.into_inner()).as_ref().and_then(StreamHandle::thread_id);
        own.or(*self.runner.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

static STREAMS: Registry<CStream> = Registry::new();

fn config(c: &bass_stream_config) -> Result<Config, Failure> {
    let start = match c.start {
        BASS_START_OLDEST => Start::Oldest,
        BASS_START_NOW => Start::Now,
        BASS_START_FRAME => Start::Frame(c.start_frame),
        s => {
            return Err(Error::InvalidArgument(format!(
                "config.start = {s} (BASS_START_OLDEST, _NOW or _FRAME)"
            ))
            .into())
        }
    };
    let channels = if c.channels.is_null() || c.n_channels == 0 {
        Vec::new()
    } else if c.n_channels > 64 {
        return Err(
            Error::InvalidArgument(format!("config.n_channels = {} (at most 64)", c.n_channels)).into()
        );
    } else {
        // SAFETY: non-null, and the caller guarantees `n_channels` readable entries.
        unsafe { std::slice::from_raw_parts(c.channels, c.n_channels) }.to_vec()
    };
    let layout = if c.interleaved != 0 { SampleLayout::Interleaved } else { SampleLayout::Planar };
    let realtime_priority = (c.realtime_priority != 0).then_some(c.realtime_priority);
    Ok(Config { frames_per_call: c.frames_per_call, start, channels, layout, realtime_priority })
}

/// The closures that call the C callbacks (all buffers allocated here, before the stream runs);
/// `epoch` is the stream's current one (events carry it).
#[allow(clippy::type_complexity)]
fn closures(
    (on_block, on_event, user): (bass_block_fn, bass_event_fn, User),
    mut epoch: u64,
) -> (impl FnMut(&Block<'_>) -> Control + Send, impl FnMut(&Event<'_>) -> Control + Send) {
    let mut pointers = Pointers(Vec::with_capacity(64));
    let block_user = user;
    let block = move |b: &Block<'_>| {
        let Some(f) = on_block else { return Control::Continue };
        let u = block_user;
        let pointers = pointers.vec();
        pointers.clear(); // capacity 64 (the most channels): never reallocates
        let interleaved = match b.interleaved() {
            Some(s) => s.as_ptr(),
            None => {
                pointers.extend((0..b.channels().len()).filter_map(|k| b.channel(k)).map(<[i32]>::as_ptr));
                std::ptr::null()
            }
        };
        let cb = bass_block {
            epoch: b.epoch,
            first_frame: b.first_frame,
            frames: b.frames,
            lost: b.lost,
            mono_ns: b.mono_ns,
            realtime_ns: b.realtime_ns,
            rate_hz: b.rate_hz,
            flags: b.flags,
            n_channels: b.channels().len() as u32,
            port_channels: b.channels().as_ptr(),
            channels: if interleaved.is_null() { pointers.as_ptr() } else { std::ptr::null() },
            interleaved,
        };
        // SAFETY: the caller's callback, given a block valid for the call and its own pointer.
        if unsafe { f(&cb, u.0) } == 0 {
            Control::Continue
        } else {
            Control::Stop
        }
    };
    let mut message = [0u8; MESSAGE_LEN + 1];
    let event = move |e: &Event<'_>| {
        let mut ev =
            bass_stream_event { kind: 0, code: 0, epoch, frame: 0, os_error: 0, message: c"".as_ptr() };
        match *e {
            Event::Stopped { last } => (ev.kind, ev.frame) = (BASS_EVENT_STOPPED, last),
            Event::Restarted { epoch: new, resume_at } => {
                epoch = new;
                (ev.kind, ev.epoch, ev.frame) = (BASS_EVENT_RESTARTED, new, resume_at);
            }
            Event::Device { code, message: m } => {
                let n = m.len().min(MESSAGE_LEN);
                message[..n].copy_from_slice(&m.as_bytes()[..n]);
                message[n] = 0;
                (ev.kind, ev.code, ev.message) = (BASS_EVENT_DEVICE, code, message.as_ptr().cast());
            }
            Event::Resumed { epoch: same, resume_at } => {
                epoch = same;
                (ev.kind, ev.epoch, ev.frame) = (BASS_EVENT_RESUMED, same, resume_at);
            }
            Event::WriterGone { pid } => (ev.kind, ev.code) = (BASS_EVENT_WRITER_GONE, pid),
            Event::RealtimeRefused { errno } => (ev.kind, ev.os_error) = (BASS_EVENT_REALTIME_REFUSED, errno),
        }
        // Without an event callback every end ends the stream; a refused priority is no end.
        let Some(f) = on_event else {
            return match e {
                Event::RealtimeRefused { .. } => Control::Continue,
                _ => Control::Stop,
            };
        };
        let u = user;
        // SAFETY: the caller's callback, given an event valid for the call and its own pointer.
        if unsafe { f(&ev, u.0) } == 0 {
            Control::Continue
        } else {
            Control::Stop
        }
    };
    (block, event)
}

/// Builds a stream (no thread yet) and registers it.
///
/// # Safety
/// As for [`bass_stream_start`].
unsafe fn create(
    port: *const bass_port,
    config_: *const bass_stream_config,
    on_block: bass_block_fn,
    on_event: bass_event_fn,
    user: *mut c_void,
) -> Result<(usize, Arc<CStream>), Failure> {
    let port = super::port::port_arc(port)?;
    let cfg = nonnull(config_, "config")?;
    // SAFETY: checked non-null; the caller guarantees a valid config.
    let cfg = config(unsafe { &*cfg })?;
    if on_block.is_none() {
        return Err(Failure::Null("on_block"));
    }
    let stream = Stream::new(port, cfg)?;
    let c = CStream {
        stopper: stream.stopper(),
        idle: Mutex::new(Some(stream)),
        handle: Mutex::new(None),
        runner: Mutex::new(None),
        run_ended: Condvar::new(),
        callbacks: (on_block, on_event, User(user)),
    };
    let id = STREAMS.insert(c);
    Ok((id, STREAMS.get(id)?))
}

/// Creates a callback stream on `port` without starting it: run it on your own thread with
/// `bass_stream_run` (as `jack_set_process_thread` allows), stop it with `bass_stream_stop`,
/// release it with `bass_stream_close`. `on_block` receives every block (required); `on_event`
/// the acquisition events (nullable: every event then ends the stream). The port handle may
/// be closed afterwards: the stream keeps its own reference.
///
/// # Safety
/// `config` must be NULL or valid (with `channels` valid for `n_channels` reads); `user` is
/// passed to the callbacks untouched; `out_stream` NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_stream_create(
    port: *const bass_port,
    config: *const bass_stream_config,
    on_block: bass_block_fn,
    on_event: bass_event_fn,
    user: *mut c_void,
    out_stream: *mut *mut bass_stream,
) -> bass_result {
    boundary("bass_stream_create", || {
        let out = nonnull_mut(out_stream, "out_stream")?;
        // SAFETY: forwarded caller guarantee.
        let (id, _) = unsafe { create(port, config, on_block, on_event, user) }?;
        // SAFETY: checked non-null; the caller guarantees validity.
        unsafe { put(out, id as *mut bass_stream) };
        Ok(())
    })
}

/// Creates a callback stream on `port` (see `bass_stream_create`) and starts it on a thread
/// of bass's own (`bass-stream`; SCHED_FIFO at `config.realtime_priority` if not 0; refused:
/// a `BASS_EVENT_REALTIME_REFUSED` event, and the stream goes on).
///
/// # Safety
/// As for `bass_stream_create`; the callbacks and `user` must be usable from another thread.
#[no_mangle]
pub unsafe extern "C" fn bass_stream_start(
    port: *const bass_port,
    config: *const bass_stream_config,
    on_block: bass_block_fn,
    on_event: bass_event_fn,
    user: *mut c_void,
    out_stream: *mut *mut bass_stream,
) -> bass_result {
    boundary("bass_stream_start", || {
        let out = nonnull_mut(out_stream, "out_stream")?;
        // SAFETY: forwarded caller guarantee.
        let (id, c) = unsafe { create(port, config, on_block, on_event, user) }?;
        let stream = c.idle.lock().unwrap_or_else(|e| e.into_inner()).take().ok_or(Failure::Handle)?;
        let (b, e) = closures(c.callbacks, stream.port().epoch());
        match stream.spawn(b, e) {
            Ok(h) => *c.handle.lock().unwrap_or_else(|e| e.into_inner()) = Some(h),
            Err(err) => {
                let _ = STREAMS.remove(id);
                return Err(err.into());
            }
        }
        // SAFETY: checked non-null; the caller guarantees validity.
        unsafe { put(out, id as *mut bass_stream) };
        Ok(())
    })
}

/// Runs a stream made by `bass_stream_create` on the calling thread until a callback returns
/// non-zero, `bass_stream_stop` is called, or an error ends it (`BASS_OK` for the first two).
/// A stream that returned may be run again; it goes on where it stopped.
///
/// # Safety
/// None beyond passing a handle from `bass_stream_create`.
#[no_mangle]
pub unsafe extern "C" fn bass_stream_run(stream: *mut bass_stream) -> bass_result {
    boundary("bass_stream_run", || {
        let c = STREAMS.get(nonnull(stream, "stream")? as usize)?;
        let taken = {
            let mut runner = c.runner.lock().unwrap_or_else(|e| e.into_inner());
            let taken = c.idle.lock().unwrap_or_else(|e| e.into_inner()).take();
            if taken.is_some() {
                *runner = Some(std::thread::current().id());
            }
            taken
        };
        let mut s = taken.ok_or_else(|| {
            Failure::Lib(Error::InvalidArgument(
                "the stream is running (started by bass_stream_start, or in another bass_stream_run)".into(),
            ))
        })?;
        let (b, e) = closures(c.callbacks, s.port().epoch());
        // A panic in `run` unwinds through here to the boundary: the guard still ends the run.
        struct Ended<'a>(&'a CStream);
        impl Drop for Ended<'_> {
            fn drop(&mut self) {
                *self.0.runner.lock().unwrap_or_else(|e| e.into_inner()) = None;
                self.0.run_ended.notify_all();
            }
        }
        let ended = Ended(&c);
        let r = s.run(b, e);
        *c.idle.lock().unwrap_or_else(|e| e.into_inner()) = Some(s);
        drop(ended);
        r.map_err(Failure::from)
    })
}

/// Asks a stream to stop; safe from any thread, also from inside its callbacks. No block
/// starts after it returns; a stream waiting for frames notices within 50 ms. Does not wait.
///
/// # Safety
/// None beyond passing a handle from `bass_stream_create` / `bass_stream_start`.
#[no_mangle]
pub unsafe extern "C" fn bass_stream_stop(stream: *mut bass_stream) -> bass_result {
    boundary("bass_stream_stop", || {
        STREAMS.get(nonnull(stream, "stream")? as usize)?.stopper.stop();
        Ok(())
    })
}

/// Stops a stream, waits until its callbacks have returned (its thread joined, or a
/// `bass_stream_run` on another thread returned) and releases it; returns how its run on
/// bass's thread ended (`BASS_OK`, or the error that ended it). Not from inside its own
/// callbacks (`BASS_ERR_INVALID_ARGUMENT`: use `bass_stream_stop` there). Closing NULL does
/// nothing.
///
/// # Safety
/// None beyond passing a handle from `bass_stream_create` / `bass_stream_start`.
#[no_mangle]
pub unsafe extern "C" fn bass_stream_close(stream: *mut bass_stream) -> bass_result {
    boundary("bass_stream_close", || {
        if stream.is_null() {
            return Ok(());
        }
        let c = STREAMS.get(stream as usize)?;
        if c.running_thread() == Some(std::thread::current().id()) {
            return Err(Error::InvalidArgument(
                "bass_stream_close called from a stream's callback (call bass_stream_stop there)".into(),
            )
            .into());
        }
        let c = STREAMS.remove(stream as usize)?;
        c.stopper.stop();
        // A run on a caller's thread: wait for it to return (its callbacks may use `user`).
        let mut runner = c.runner.lock().unwrap_or_else(|e| e.into_inner());
        while runner.is_some() {
            runner = c.run_ended.wait(runner).unwrap_or_else(|e| e.into_inner());
        }
        drop(runner);
        let handle = c.handle.lock().unwrap_or_else(|e| e.into_inner()).take();
        match handle {
            Some(h) => h.join().1.map_err(Failure::from),
            None => Ok(()),
        }
    })
}
