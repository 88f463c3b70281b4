//! C ABI of the port reader: open, `bass_get_audio_data`, info, wait, chunk metadata and
//! zero-copy views. Conventions in [`super`].

use std::ffi::c_char;
use std::sync::Arc;
use std::time::Duration;

use super::bass_result;
use super::{
    boundary, c_str, copy_text, nonnull, nonnull_mut, put, Failure, Registry, BASS_DEVICE_LEN,
    BASS_MESSAGE_LEN, BASS_WAIT_FOREVER,
};
use bassport::error::Error;
use bassport::reader::{ChunkInfo, Port, PortInfo, View};

/// Opaque handle of an open port (reader).
pub struct bass_port {
    _private: [u8; 0],
}

/// A snapshot of a port's header.
#[repr(C)]
pub struct bass_port_info {
    /// Channels.
    pub channels: u32,
    /// Sample rate in Hz.
    pub sample_rate: u32,
    /// nFramesPerChunk.
    pub frames_per_chunk: u32,
    /// nChunksOnPort.
    pub chunks_on_port: u32,
    /// nFOP = nFramesPerChunk * nChunksOnPort.
    pub frames_on_port: u64,
    /// Index of the newest frame (frames are numbered from 1; 0 = none yet).
    pub last_frame_index: u64,
    /// Acquisition epoch (changes with every new acquisition).
    pub epoch: u64,
    /// `BASS_STATE_*`.
    pub state: u32,
    /// `BASS_DEVERR_*` when `state` is `BASS_STATE_ERROR`.
    pub error_code: u32,
    /// Recovered device overruns.
    pub xruns: u64,
    /// Zero-filled frames published for device gaps.
    pub gap_frames: u64,
    /// Chunks published.
    pub chunks_published: u64,
    /// Estimated device sample rate in Hz (0 = no estimate yet).
    pub rate_estimate_hz: f64,
    /// Broker process id (in the broker's own pid namespace).
    pub writer_pid: u32,
    /// 1 if the broker process is alive (in another pid namespace: if its heartbeat is
    /// younger than 2 s plus two chunk periods).
    pub writer_alive: u32,
    /// CLOCK_MONOTONIC (ns) when the acquisition started.
    pub started_mono_ns: u64,
    /// CLOCK_MONOTONIC (ns) of the broker's last publish or heartbeat.
    pub heartbeat_mono_ns: u64,
    /// Device name, NUL terminated.
    pub device: [c_char; BASS_DEVICE_LEN],
    /// Error message, NUL terminated.
    pub message: [c_char; BASS_MESSAGE_LEN],
    /// Frames lost upstream of this port or on the network (a replica port written by
    /// `bass-bridge mirror`), published as zero-filled GAP frames and also counted in
    /// `gap_frames`; 0 for a local broker's port. Added at the end in port format 2.1.
    pub lost_upstream_frames: u64,
}

/// Timestamps and flags of one chunk.
#[repr(C)]
pub struct bass_chunk_info {
    /// First frame of the chunk.
    pub first_frame: u64,
    /// CLOCK_MONOTONIC (ns) of the first frame.
    pub mono_ns: u64,
    /// CLOCK_REALTIME (ns) of the first frame.
    pub realtime_ns: u64,
    /// Frames in the chunk.
    pub frames: u32,
    /// `BASS_CHUNK_*` flags.
    pub flags: u32,
}

/// What port format 2.4's chunk extension table says of one chunk (`bass_port_chunk_ext`).
#[repr(C)]
pub struct bass_chunk_ext {
    /// First frame of the chunk.
    pub first_frame: u64,
    /// Bound (ns) of the chunk's timestamps: the first frame's true capture time lies within
    /// `mono_ns ± bound_ns` of `bass_chunk_info`; `BASS_BOUND_UNKNOWN` if no bound is known
    /// (also for every chunk of a port written before format 2.4).
    pub bound_ns: u64,
    /// Bit c set: channel c's frames in this chunk are zero-filled because the device feeding
    /// it lost them (a follower device of a multi-device acquisition); the chunk is no GAP.
    pub missing_channels: u64,
    /// Bit c set: channel c comes from a follower device not yet aligned within its bound.
    pub unaligned_channels: u64,
}

/// Frames to be read in place in the port mapping (zero-copy). Each channel's frames are
/// `seg_frames[0]` samples at segment 0 followed by `seg_frames[1]` at segment 1.
#[repr(C)]
pub struct bass_view {
    /// First frame of the view.
    pub first_frame: u64,
    /// Frames in the view.
    pub frames: usize,
    /// Frames lost before the view.
    pub loss: u64,
    /// Frames in each segment.
    pub seg_frames: [usize; 2],
    /// Slot (sample offset in each channel ring) of each segment.
    pub seg_offset: [usize; 2],
    /// Channel 0 segments (valid while the port is open).
    pub left: [*const i32; 2],
    /// Channel 1 segments (NULL on a mono port).
    pub right: [*const i32; 2],
}

static PORTS: Registry<Port> = Registry::new();

fn port(p: *const bass_port) -> Result<Arc<Port>, Failure> {
    PORTS.get(nonnull(p, "port")? as usize)
}

/// The port behind a handle, for the callback stream (ffi/stream.rs).
pub(super) fn port_arc(p: *const bass_port) -> Result<Arc<Port>, Failure> {
    port(p)
}

/// Refuses output buffers that overlap (they become `&mut` slices, which must not alias).
fn check_disjoint(ptrs: &[*mut i32], len: usize) -> Result<(), Failure> {
    let bytes = len * std::mem::size_of::<i32>();
    for (i, &a) in ptrs.iter().enumerate() {
        for (j, &b) in ptrs.iter().enumerate().skip(i + 1) {
            let (a, b) = (a as usize, b as usize);
            if len > 0 && a < b + bytes && b < a + bytes {
                return Err(Error::InvalidArgument(format!(
                    "output buffers for channels {i} and {j} overlap"
                ))
                .into());
            }
        }
    }
    Ok(())
}

/// Opens the port `name` (in `$BASS_RUNTIME_DIR`, default /dev/shm) read-only. The file is
/// not opened through a symbolic link, and its owner must be root, the caller (or
/// `$BASS_BROKER_UID`) or the owner of a runtime directory nobody else can write, else
/// `BASS_ERR_WRONG_OWNER`. A file whose header stays unwritten is `BASS_ERR_NOT_READY` for
/// 2 s after its last change, then `BASS_ERR_NEVER_READY`.
///
/// The first port file a process maps installs a SIGBUS handler that turns a port file
/// shrunk under the mapping into `BASS_ERR_CORRUPT` of the calls that touch it (other SIGBUS
/// go to the handler installed before, or kill the process as usual). A host that installs
/// its own SIGBUS handler afterwards must chain to the previous one, or set
/// `BASS_SIGBUS_GUARD=0` (then every call checks the file's size instead).
///
/// # Safety
/// `name` must be NULL or a NUL-terminated string; `out_port` NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_port_open(name: *const c_char, out_port: *mut *mut bass_port) -> bass_result {
    boundary("bass_port_open", || {
        // SAFETY: forwarded caller guarantee.
        let name = unsafe { c_str(name, "name") }?;
        let out = nonnull_mut(out_port, "out_port")?;
        let id = PORTS.insert(Port::open(name)?);
        // SAFETY: checked non-null; the caller guarantees validity.
        unsafe { put(out, id as *mut bass_port) };
        Ok(())
    })
}

/// Opens the port file at `path` read-only (guarded against SIGBUS like `bass_port_open`).
///
/// # Safety
/// `path` must be NULL or a NUL-terminated string; `out_port` NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_port_open_path(
    path: *const c_char,
    out_port: *mut *mut bass_port,
) -> bass_result {
    boundary("bass_port_open_path", || {
        // SAFETY: forwarded caller guarantee.
        let path = unsafe { c_str(path, "path") }?;
        let out = nonnull_mut(out_port, "out_port")?;
        let id = PORTS.insert(Port::open_path(std::path::Path::new(path))?);
        // SAFETY: checked non-null; the caller guarantees validity.
        unsafe { put(out, id as *mut bass_port) };
        Ok(())
    })
}

/// Closes a port. Closing NULL does nothing and returns `BASS_OK`; closing twice returns
/// `BASS_ERR_INVALID_HANDLE`. Pointers from `bass_port_view` die with the handle.
///
/// # Safety
/// None beyond passing a value returned by `bass_port_open` (anything else is reported).
#[no_mangle]
pub unsafe extern "C" fn bass_port_close(port: *mut bass_port) -> bass_result {
    boundary("bass_port_close", || {
        if port.is_null() {
            return Ok(());
        }
        PORTS.remove(port as usize).map(drop)
    })
}

/// The formal `getAudioData` of the BASS documentation on a stereo port (channels 0 and 1):
/// copies up to `n_frames` frames from `*nfr` into `left` and `right`, sets `*out_n`, the
/// frames lost (`*out_loss`: frames that left the window before being read; the block then
/// starts at the oldest frame) and advances `*nfr`. Never blocks. `nfr` beyond the newest
/// frame gives `*out_n = 0`.
///
/// # Safety
/// `left` and `right` must be valid for `n_frames` writes of `int32_t` (only `*out_n` are
/// written; overlapping buffers are refused); the other pointers valid for one read/write each.
#[no_mangle]
pub unsafe extern "C" fn bass_get_audio_data(
    port: *const bass_port,
    n_frames: usize,
    nfr: *mut u64,
    left: *mut i32,
    right: *mut i32,
    out_n: *mut usize,
    out_loss: *mut u64,
) -> bass_result {
    boundary("bass_get_audio_data", || {
        let p = self::port(port)?;
        let nfr = nonnull_mut(nfr, "nfr")?;
        let left = nonnull_mut(left, "left")?;
        let right = nonnull_mut(right, "right")?;
        let (out_n, out_loss) = (nonnull_mut(out_n, "out_n")?, nonnull_mut(out_loss, "out_loss")?);
        if p.geometry().channels < 2 {
            return Err(Error::InvalidArgument(format!(
                "the port has {} channel; use bass_get_audio_data_multi",
                p.geometry().channels
            ))
            .into());
        }
        let len = output_len(&p, n_frames);
        check_disjoint(&[left, right], len)?;
        // SAFETY: the caller guarantees `n_frames` writable samples behind each pointer and
        // len <= n_frames; check_disjoint above refused overlapping buffers.
        let mut out = unsafe {
            [std::slice::from_raw_parts_mut(left, len), std::slice::from_raw_parts_mut(right, len)]
        };
        // SAFETY: the three pointers were checked non-null; the caller guarantees validity.
        unsafe { read_and_report(&p, n_frames, nfr, &mut out, out_n, out_loss) }
    })
}

/// `getAudioData` for any number of channels: `channels[c]` receives channel `c` for
/// `c < n_channels` (`n_channels` at most the port's channel count).
///
/// # Safety
/// `channels` must point to `n_channels` pointers, each valid for `n_frames` writes of
/// `int32_t` and not overlapping; the other pointers valid for one read/write each.
#[no_mangle]
pub unsafe extern "C" fn bass_get_audio_data_multi(
    port: *const bass_port,
    n_frames: usize,
    nfr: *mut u64,
    channels: *const *mut i32,
    n_channels: usize,
    out_n: *mut usize,
    out_loss: *mut u64,
) -> bass_result {
    boundary("bass_get_audio_data_multi", || {
        let p = self::port(port)?;
        let nfr = nonnull_mut(nfr, "nfr")?;
        let channels = nonnull(channels, "channels")?;
        let (out_n, out_loss) = (nonnull_mut(out_n, "out_n")?, nonnull_mut(out_loss, "out_loss")?);
        if n_channels == 0 || n_channels > p.geometry().channels as usize {
            return Err(Error::InvalidArgument(format!(
                "n_channels = {n_channels}; the port has {} channels",
                p.geometry().channels
            ))
            .into());
        }
        let len = output_len(&p, n_frames);
        // SAFETY: the caller guarantees `n_channels` readable pointers.
        let ptrs = unsafe { std::slice::from_raw_parts(channels, n_channels) };
        check_disjoint(ptrs, len)?;
        let mut out = Vec::with_capacity(n_channels);
        for (c, &ptr) in ptrs.iter().enumerate() {
            if ptr.is_null() {
                return Err(Failure::NullAt("channels", c));
            }
            // SAFETY: the caller guarantees `n_frames` >= len writable, non-overlapping samples.
            out.push(unsafe { std::slice::from_raw_parts_mut(ptr, len) });
        }
        // SAFETY: the three pointers were checked non-null; the caller guarantees validity.
        unsafe { read_and_report(&p, n_frames, nfr, &mut out, out_n, out_loss) }
    })
}

/// Samples of each output buffer the library may write: only min(N, nFOP) frames can ever
/// be delivered, so the slices made from the caller's buffers are no longer than that.
fn output_len(p: &Port, n_frames: usize) -> usize {
    (n_frames as u64).min(p.frames_on_port()) as usize
}

/// The shared tail of the getAudioData exports: reads `*nfr`, runs the algorithm into `out`,
/// and writes `*nfr`, `*out_n` and `*out_loss` only on success.
///
/// # Safety
/// `nfr`, `out_n` and `out_loss` must be non-null and valid for a read/write.
unsafe fn read_and_report(
    p: &Port,
    n_frames: usize,
    nfr: *mut u64,
    out: &mut [&mut [i32]],
    out_n: *mut usize,
    out_loss: *mut u64,
) -> Result<(), Failure> {
    // SAFETY: guaranteed by the caller.
    let mut next = unsafe { nfr.read() };
    let r = p.get_audio_data(n_frames, &mut next, out)?;
    // SAFETY: guaranteed by the caller.
    unsafe {
        put(nfr, next);
        put(out_n, r.frames);
        put(out_loss, r.loss);
    }
    Ok(())
}

fn info_to_c(i: &PortInfo) -> bass_port_info {
    let mut out = bass_port_info {
        channels: i.geometry.channels,
        sample_rate: i.geometry.sample_rate,
        frames_per_chunk: i.geometry.frames_per_chunk,
        chunks_on_port: i.geometry.chunks_on_port,
        frames_on_port: i.frames_on_port,
        last_frame_index: i.last_frame_index,
        epoch: i.epoch,
        state: i.state.map_or(u32::MAX, |s| s as u32),
        error_code: i.error_code,
        xruns: i.xruns,
        gap_frames: i.gap_frames,
        chunks_published: i.chunks_published,
        rate_estimate_hz: i.rate_estimate_hz,
        writer_pid: i.writer_pid,
        writer_alive: u32::from(i.writer_alive),
        started_mono_ns: i.started_mono_ns,
        heartbeat_mono_ns: i.heartbeat_mono_ns,
        device: [0; BASS_DEVICE_LEN],
        message: [0; BASS_MESSAGE_LEN],
        lost_upstream_frames: i.lost_upstream_frames,
    };
    copy_text(&mut out.device, &i.device);
    copy_text(&mut out.message, &i.message);
    out
}

/// Fills `*out_info` with a snapshot of the port's header.
///
/// # Safety
/// `out_info` must be NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_port_get_info(
    port: *const bass_port,
    out_info: *mut bass_port_info,
) -> bass_result {
    boundary("bass_port_get_info", || {
        let p = self::port(port)?;
        let out = nonnull_mut(out_info, "out_info")?;
        let info = info_to_c(&p.info()?);
        // SAFETY: checked non-null; caller guarantees validity.
        unsafe { put(out, info) };
        Ok(())
    })
}

/// Blocks until frame `frame` is published (`BASS_OK`, and `*out_last_frame_index` if not
/// NULL), or returns `BASS_ERR_TIMEOUT` after `timeout_ms` (`BASS_WAIT_FOREVER`: no limit),
/// `BASS_ERR_STOPPED`, `BASS_ERR_DEVICE`, `BASS_ERR_RESTARTED`, `BASS_ERR_WRITER_GONE`
/// (detected within about 100 ms; for a broker run by systemd with the fd store, only after
/// its restart grace, 10 s by default: a restarted broker takes the port back and the wait
/// goes on) or `BASS_ERR_INTERRUPTED` (a signal). A futex wait: no CPU is used while waiting.
///
/// # Safety
/// `out_last_frame_index` must be NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_port_wait(
    port: *const bass_port,
    frame: u64,
    timeout_ms: u32,
    out_last_frame_index: *mut u64,
) -> bass_result {
    boundary("bass_port_wait", || {
        let p = self::port(port)?;
        let timeout = if timeout_ms == BASS_WAIT_FOREVER {
            Duration::MAX
        } else {
            Duration::from_millis(u64::from(timeout_ms))
        };
        let lfi = p.wait(frame, timeout)?;
        if !out_last_frame_index.is_null() {
            // SAFETY: non-null; caller guarantees validity.
            unsafe { put(out_last_frame_index, lfi) };
        }
        Ok(())
    })
}

/// Timestamps and flags of the chunk that holds `frame` (`BASS_ERR_FRAME_LOST` if it left
/// the window, `BASS_ERR_FRAME_NOT_YET` if not published yet).
///
/// # Safety
/// `out_info` must be NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_port_chunk_info(
    port: *const bass_port,
    frame: u64,
    out_info: *mut bass_chunk_info,
) -> bass_result {
    boundary("bass_port_chunk_info", || {
        let p = self::port(port)?;
        let out = nonnull_mut(out_info, "out_info")?;
        let ChunkInfo { first_frame, frames, mono_ns, realtime_ns, flags, .. } = p.chunk_info(frame)?;
        // SAFETY: checked non-null; caller guarantees validity.
        unsafe { put(out, bass_chunk_info { first_frame, mono_ns, realtime_ns, frames, flags }) };
        Ok(())
    })
}

/// The timestamp bound and channel masks of the chunk that holds `frame` (port format 2.4's
/// chunk extension table; see `bass_chunk_ext`), with the errors of `bass_port_chunk_info`.
/// A port without the table (an older writer) gives `BASS_BOUND_UNKNOWN` and empty masks.
///
/// # Safety
/// `out_ext` must be NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_port_chunk_ext(
    port: *const bass_port,
    frame: u64,
    out_ext: *mut bass_chunk_ext,
) -> bass_result {
    boundary("bass_port_chunk_ext", || {
        let p = self::port(port)?;
        let out = nonnull_mut(out_ext, "out_ext")?;
        let c = p.chunk_info(frame)?;
        let ext = bass_chunk_ext {
            first_frame: c.first_frame,
            bound_ns: c.bound_ns,
            missing_channels: c.missing_channels,
            unaligned_channels: c.unaligned_channels,
        };
        // SAFETY: checked non-null; caller guarantees validity.
        unsafe { put(out, ext) };
        Ok(())
    })
}

fn view_to_c(p: &Port, v: &View) -> bass_view {
    let seg = |c: usize| -> [*const i32; 2] {
        match p.channel_ring(c) {
            Some(ring) => {
                [ring.as_ptr().wrapping_add(v.segments[0].0), ring.as_ptr().wrapping_add(v.segments[1].0)]
            }
            None => [std::ptr::null(); 2],
        }
    };
    bass_view {
        first_frame: v.first_frame,
        frames: v.frames,
        loss: v.loss,
        seg_frames: [v.segments[0].1, v.segments[1].1],
        seg_offset: [v.segments[0].0, v.segments[1].0],
        left: seg(0),
        right: seg(1),
    }
}

/// Zero-copy read: like `bass_get_audio_data`, but instead of copying, describes where the
/// frames lie in the port mapping (`*out_view`) and advances `*nfr` past them. Read them in
/// place, then call `bass_port_view_check`: frames it reports overwritten must be treated as
/// lost. The pointers stay valid while the port is open.
///
/// # Safety
/// `nfr` must be valid for a read and a write, `out_view` for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_port_view(
    port: *const bass_port,
    n_frames: usize,
    nfr: *mut u64,
    out_view: *mut bass_view,
) -> bass_result {
    boundary("bass_port_view", || {
        let p = self::port(port)?;
        let nfr = nonnull_mut(nfr, "nfr")?;
        let out = nonnull_mut(out_view, "out_view")?;
        // SAFETY: checked non-null; caller guarantees validity.
        let mut next = unsafe { nfr.read() };
        let v = p.view(n_frames, &mut next)?;
        let cv = view_to_c(&p, &v);
        // SAFETY: checked non-null; caller guarantees validity.
        unsafe {
            put(nfr, next);
            put(out, cv);
        }
        Ok(())
    })
}

/// The segments of channel `channel` for a view (for ports with more than two channels).
///
/// # Safety
/// `view` must be valid for a read; `out_seg0`, `out_seg1` for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_port_view_channel(
    port: *const bass_port,
    view: *const bass_view,
    channel: u32,
    out_seg0: *mut *const i32,
    out_seg1: *mut *const i32,
) -> bass_result {
    boundary("bass_port_view_channel", || {
        let p = self::port(port)?;
        let view = nonnull(view, "view")?;
        let (o0, o1) = (nonnull_mut(out_seg0, "out_seg0")?, nonnull_mut(out_seg1, "out_seg1")?);
        // SAFETY: checked non-null; caller guarantees validity.
        let v = unsafe { &*view };
        let nfop = p.frames_on_port() as usize;
        if v.seg_offset[0] >= nfop || v.seg_offset[1] >= nfop {
            return Err(Error::InvalidArgument("view offsets outside the window".into()).into());
        }
        let ring = p.channel_ring(channel as usize).ok_or_else(|| {
            Error::InvalidArgument(format!("channel = {channel}; the port has {}", p.geometry().channels))
        })?;
        // SAFETY: checked non-null; caller guarantees validity.
        unsafe {
            put(o0, ring.as_ptr().wrapping_add(v.seg_offset[0]));
            put(o1, ring.as_ptr().wrapping_add(v.seg_offset[1]));
        }
        Ok(())
    })
}

/// After reading a view in place: `*out_overwritten` = how many frames at the start of the
/// view may have been overwritten meanwhile (0 = all intact). Those frames are lost.
///
/// # Safety
/// `view` must be valid for a read, `out_overwritten` for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_port_view_check(
    port: *const bass_port,
    view: *const bass_view,
    out_overwritten: *mut u64,
) -> bass_result {
    boundary("bass_port_view_check", || {
        let p = self::port(port)?;
        let view = nonnull(view, "view")?;
        let out = nonnull_mut(out_overwritten, "out_overwritten")?;
        // SAFETY: checked non-null; caller guarantees validity.
        let v = unsafe { &*view };
        let rv = View { first_frame: v.first_frame, frames: v.frames, loss: v.loss, segments: [(0, 0); 2] };
        // SAFETY: checked non-null; caller guarantees validity.
        unsafe { put(out, p.view_overwritten(&rv)) };
        Ok(())
    })
}
