//! C ABI of the port writer, for simulators and test rigs: create, publish, set state, close.
//! Conventions in [`super`].

use std::ffi::c_char;
use std::sync::{Arc, Mutex};

use super::bass_result;
use super::port::bass_chunk_ext;
use super::{boundary, c_str, nonnull, nonnull_mut, put, Failure, Registry};
use bassport::error::Error;
use bassport::format::{self, chunk_flags, Geometry, State};
use bassport::ring::Source;
use bassport::writer::{ChunkMeta, PortParams, Writer};

/// Opaque handle of a port writer.
pub struct bass_writer {
    _private: [u8; 0],
}

/// Timestamps and flags given with a published chunk (0 timestamps mean "now").
#[repr(C)]
pub struct bass_chunk_meta {
    /// CLOCK_MONOTONIC (ns) of the chunk's first frame.
    pub mono_ns: u64,
    /// CLOCK_REALTIME (ns) of the chunk's first frame.
    pub realtime_ns: u64,
    /// `BASS_CHUNK_*` flags.
    pub flags: u32,
}

/// A writer handle: the port writer and what `bass_writer_set_chunk_ext` gave for its next
/// chunk.
struct CWriter {
    w: Writer,
    /// Bound and masks of the next chunk published (one chunk only).
    next_ext: Option<(Option<u64>, u64, u64)>,
}

static WRITERS: Registry<Mutex<CWriter>> = Registry::new();

fn writer(w: *mut bass_writer) -> Result<Arc<Mutex<CWriter>>, Failure> {
    WRITERS.get(nonnull_mut(w, "writer")? as usize)
}

/// Runs `f` on the handle's writer with `meta` completed by the pending chunk extension
/// (taken: it is for one chunk).
fn with_ext<T>(
    w: &Mutex<CWriter>,
    mut meta: ChunkMeta,
    f: impl FnOnce(&mut Writer, ChunkMeta) -> Result<T, Error>,
) -> Result<T, Failure> {
    let mut g = w.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((bound, missing, unaligned)) = g.next_ext.take() {
        (meta.bound_ns, meta.missing_channels, meta.unaligned_channels) = (bound, missing, unaligned);
    }
    Ok(f(&mut g.w, meta)?)
}

/// Creates the port `name` for writing (mode 0640, in `$BASS_RUNTIME_DIR` or /dev/shm),
/// replacing a port of that name whose writer is gone or is this process. Readers of the
/// replaced port get `BASS_ERR_RESTARTED`. The geometry comes in the order of
/// `bass_acquire`: sample rate, nFramesPerChunk, nChunksOnPort, channels.
///
/// # Safety
/// `name` and `device` (may be NULL) must be NUL-terminated; `out_writer` valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_writer_create(
    name: *const c_char,
    device: *const c_char,
    sample_rate: u32,
    frames_per_chunk: u32,
    chunks_on_port: u32,
    channels: u32,
    out_writer: *mut *mut bass_writer,
) -> bass_result {
    boundary("bass_writer_create", || {
        // SAFETY: forwarded caller guarantee.
        let name = unsafe { c_str(name, "name") }?;
        // SAFETY: forwarded caller guarantee.
        let device = if device.is_null() { "" } else { unsafe { c_str(device, "device") }? };
        let out = nonnull_mut(out_writer, "out_writer")?;
        let params = PortParams {
            geometry: Geometry { channels, sample_rate, frames_per_chunk, chunks_on_port },
            device: device.to_owned(),
            group: None,
        };
        let id = WRITERS.insert(Mutex::new(CWriter { w: Writer::create(name, &params)?, next_ext: None }));
        // SAFETY: checked non-null; caller guarantees validity.
        unsafe { put(out, id as *mut bass_writer) };
        Ok(())
    })
}

/// # Safety
/// `meta` must be NULL or valid for a read.
unsafe fn meta_from(meta: *const bass_chunk_meta) -> ChunkMeta {
    if meta.is_null() {
        return ChunkMeta::default();
    }
    // SAFETY: non-null; caller guarantees validity.
    let m = unsafe { &*meta };
    ChunkMeta { mono_ns: m.mono_ns, realtime_ns: m.realtime_ns, flags: m.flags, ..ChunkMeta::default() }
}

fn publish(w: *mut bass_writer, src: Source<'_>, meta: ChunkMeta, out_lfi: *mut u64) -> Result<(), Failure> {
    let w = writer(w)?;
    let lfi = with_ext(&w, meta, |w, meta| w.publish(src, meta))?;
    if !out_lfi.is_null() {
        // SAFETY: non-null; the exporting function's caller guarantees validity.
        unsafe { put(out_lfi, lfi) };
    }
    Ok(())
}

/// Publishes one chunk of interleaved samples (`n_samples` = nFramesPerChunk × channels).
/// `meta` (NULL: now, no flags) gives its timestamps; `*out_last_frame_index` (if not NULL)
/// receives the new last frame index.
///
/// # Safety
/// `samples` must be valid for `n_samples` reads; `meta` NULL or valid; `out_last_frame_index`
/// NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_writer_publish_interleaved(
    writer: *mut bass_writer,
    samples: *const i32,
    n_samples: usize,
    meta: *const bass_chunk_meta,
    out_last_frame_index: *mut u64,
) -> bass_result {
    boundary("bass_writer_publish_interleaved", || {
        let samples = nonnull(samples, "samples")?;
        // SAFETY: non-null; caller guarantees `n_samples` readable samples.
        let s = unsafe { std::slice::from_raw_parts(samples, n_samples) };
        // SAFETY: forwarded caller guarantee.
        let meta = unsafe { meta_from(meta) };
        publish(writer, Source::Interleaved(s), meta, out_last_frame_index)
    })
}

/// Publishes one chunk given as one array of `n_frames` (= nFramesPerChunk) samples per
/// channel (`n_channels` = the port's channels).
///
/// # Safety
/// `channels` must point to `n_channels` pointers each valid for `n_frames` reads; `meta`
/// NULL or valid; `out_last_frame_index` NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_writer_publish_planar(
    writer: *mut bass_writer,
    channels: *const *const i32,
    n_channels: usize,
    n_frames: usize,
    meta: *const bass_chunk_meta,
    out_last_frame_index: *mut u64,
) -> bass_result {
    boundary("bass_writer_publish_planar", || {
        let channels = nonnull(channels, "channels")?;
        if n_channels > format::MAX_CHANNELS as usize {
            return Err(Error::InvalidArgument(format!("n_channels = {n_channels}")).into());
        }
        // SAFETY: caller guarantees `n_channels` readable pointers.
        let ptrs = unsafe { std::slice::from_raw_parts(channels, n_channels) };
        let mut planes = Vec::with_capacity(n_channels);
        for (c, &p) in ptrs.iter().enumerate() {
            if p.is_null() {
                return Err(Failure::NullAt("channels", c));
            }
            // SAFETY: caller guarantees `n_frames` readable samples per channel.
            planes.push(unsafe { std::slice::from_raw_parts(p, n_frames) });
        }
        // SAFETY: forwarded caller guarantee.
        let meta = unsafe { meta_from(meta) };
        publish(writer, Source::Planar(&planes), meta, out_last_frame_index)
    })
}

/// Publishes one zero-filled chunk flagged `BASS_CHUNK_GAP` (frames the device did not
/// deliver), counted in the header's gap frames.
///
/// # Safety
/// `meta` NULL or valid; `out_last_frame_index` NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_writer_publish_gap(
    writer: *mut bass_writer,
    meta: *const bass_chunk_meta,
    out_last_frame_index: *mut u64,
) -> bass_result {
    boundary("bass_writer_publish_gap", || {
        // SAFETY: forwarded caller guarantee.
        let mut meta = unsafe { meta_from(meta) };
        meta.flags |= chunk_flags::GAP;
        publish(writer, Source::Zeros, meta, out_last_frame_index)
    })
}

/// Starts a writer that has published nothing yet at frame `first_frame`: its next chunk gets
/// that index (a replica following another port's frame indices). `first_frame` must start a
/// chunk: `(first_frame - 1) % nFramesPerChunk == 0`.
///
/// # Safety
/// None beyond passing a value returned by `bass_writer_create` (anything else is reported).
#[no_mangle]
pub unsafe extern "C" fn bass_writer_start_at(writer: *mut bass_writer, first_frame: u64) -> bass_result {
    boundary("bass_writer_start_at", || {
        let w = self::writer(writer)?;
        w.lock().unwrap_or_else(|e| e.into_inner()).w.start_at(first_frame)?;
        Ok(())
    })
}

/// Publishes `n_frames` (a whole number of chunks) zero-filled frames flagged
/// `BASS_CHUNK_GAP` that stand for frames lost upstream or on the network; they are counted
/// in the port's `gap_frames` and `lost_upstream_frames`. A gap longer than the window costs
/// one window of writes. `*out_last_frame_index` (if not NULL) receives the new last frame.
///
/// # Safety
/// `meta` NULL or valid; `out_last_frame_index` NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_writer_publish_lost(
    writer: *mut bass_writer,
    n_frames: u64,
    meta: *const bass_chunk_meta,
    out_last_frame_index: *mut u64,
) -> bass_result {
    boundary("bass_writer_publish_lost", || {
        let w = self::writer(writer)?;
        // SAFETY: forwarded caller guarantee.
        let meta = unsafe { meta_from(meta) };
        let lfi = with_ext(&w, meta, |w, meta| w.publish_lost(n_frames, meta))?;
        if !out_last_frame_index.is_null() {
            // SAFETY: non-null; caller guarantees validity.
            unsafe { put(out_last_frame_index, lfi) };
        }
        Ok(())
    })
}

/// Gives the next chunk this writer publishes (by any `bass_writer_publish_*`) the timestamp
/// bound and channel masks of `ext` (port format 2.4's chunk extension; `ext->first_frame` is
/// ignored: the publish decides it). For that one chunk: the chunks after it carry
/// `BASS_BOUND_UNKNOWN` and no masks again unless this is called again. NULL clears what an
/// earlier call set. A mask bit at or past the port's channel count is `BASS_ERR_INVALID_ARGUMENT`
/// (naming the mask), and nothing is set.
///
/// # Safety
/// `ext` must be NULL or valid for a read.
#[no_mangle]
pub unsafe extern "C" fn bass_writer_set_chunk_ext(
    writer: *mut bass_writer,
    ext: *const bass_chunk_ext,
) -> bass_result {
    boundary("bass_writer_set_chunk_ext", || {
        let w = self::writer(writer)?;
        let mut g = w.lock().unwrap_or_else(|e| e.into_inner());
        if ext.is_null() {
            g.next_ext = None;
            return Ok(());
        }
        // SAFETY: non-null; caller guarantees validity.
        let e = unsafe { &*ext };
        let channels = g.w.geometry().channels;
        let past = if channels >= 64 { 0 } else { !0u64 << channels };
        for (what, mask) in
            [("missing_channels", e.missing_channels), ("unaligned_channels", e.unaligned_channels)]
        {
            if mask & past != 0 {
                return Err(Error::InvalidArgument(format!(
                    "{what} = {mask:#x}: bits at or past the port's {channels} channels"
                ))
                .into());
            }
        }
        let bound = (e.bound_ns != format::BOUND_UNKNOWN).then_some(e.bound_ns);
        g.next_ext = Some((bound, e.missing_channels, e.unaligned_channels));
        Ok(())
    })
}

/// Sets the port state (`BASS_STATE_*`), with an error code and message (may be NULL) for
/// `BASS_STATE_ERROR`, and wakes waiting readers.
///
/// # Safety
/// `message` must be NULL or NUL-terminated.
#[no_mangle]
pub unsafe extern "C" fn bass_writer_set_state(
    writer: *mut bass_writer,
    state: u32,
    error_code: u32,
    message: *const c_char,
) -> bass_result {
    boundary("bass_writer_set_state", || {
        let w = self::writer(writer)?;
        let st = match State::from_u32(state) {
            Some(s @ (State::Idle | State::Capturing | State::Stopped | State::Error | State::Starting)) => s,
            _ => {
                return Err(Error::InvalidArgument(format!(
                    "state = {state} (use BASS_STATE_IDLE..BASS_STATE_ERROR or BASS_STATE_STARTING)"
                ))
                .into())
            }
        };
        // SAFETY: forwarded caller guarantee.
        let msg = if message.is_null() { "" } else { unsafe { c_str(message, "message") }? };
        w.lock().unwrap_or_else(|e| e.into_inner()).w.set_state(st, error_code, msg);
        Ok(())
    })
}

/// Closes a writer: the port shows `BASS_STATE_STOPPED` (unless in error) and keeps its
/// frames for readers. NULL does nothing; a second close is `BASS_ERR_INVALID_HANDLE`.
///
/// # Safety
/// None beyond passing a value returned by `bass_writer_create` (anything else is reported).
#[no_mangle]
pub unsafe extern "C" fn bass_writer_close(writer: *mut bass_writer) -> bass_result {
    boundary("bass_writer_close", || {
        if writer.is_null() {
            return Ok(());
        }
        WRITERS.remove(writer as usize).map(drop)
    })
}
