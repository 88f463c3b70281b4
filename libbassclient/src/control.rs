//! The C ABI of the control plane: Acquire, Stop, Status and ListDevices on a broker.
//!
//! Each call opens a connection to the broker's control socket, sends one request, waits
//! for the reply and closes the connection (the broker keeps no per-client state). The
//! conventions of [the crate] apply: `bass_result` codes, `bass_last_error()` for the
//! detail, no panic crosses the boundary. A broker that is not running gives
//! `BASS_ERR_NO_BROKER`; a request the broker refuses gives `BASS_ERR_BROKER` with the
//! broker's message in `bass_last_error()`.

#![allow(non_camel_case_types)]

use std::ffi::c_char;

use super::{
    bass_result, boundary, c_str, copy_text, nonnull_mut, Failure, BASS_DEVICE_LEN, BASS_MESSAGE_LEN,
};
use bassport::control::{
    AcquireRequest, Client, DeviceStatus, FollowerRequest, ReplicaStatus, Status, DEFAULT_CHANNELS,
};
use bassport::paths::DEFAULT_NAME;

/// The state of a broker and of its current port, as returned by `bass_status()`.
/// (Named `bass_broker_status` because C cannot have a type and a function both named
/// `bass_status`.)
#[repr(C)]
pub struct bass_broker_status {
    /// `BASS_STATE_*` (`BASS_STATE_IDLE` before the first Acquire).
    pub state: u32,
    /// `BASS_DEVERR_*` when `state` is `BASS_STATE_ERROR`.
    pub error_code: u32,
    /// Sample rate in Hz.
    pub sample_rate: u32,
    /// nFramesPerChunk.
    pub frames_per_chunk: u32,
    /// nChunksOnPort.
    pub chunks_on_port: u32,
    /// Channels.
    pub channels: u32,
    /// Acquisition epoch (0 before the first Acquire).
    pub epoch: u64,
    /// Index of the newest published frame.
    pub last_frame_index: u64,
    /// Recovered device overruns.
    pub xruns: u64,
    /// Zero-filled frames published for device gaps.
    pub gap_frames: u64,
    /// Estimated device sample rate in Hz (0 = no estimate yet).
    pub rate_estimate_hz: f64,
    /// Device name, NUL terminated.
    pub device: [c_char; BASS_DEVICE_LEN],
    /// Error message, NUL terminated.
    pub message: [c_char; BASS_MESSAGE_LEN],
}

/// What a mirror (`bass-bridge mirror`) says of its replica and of the source it follows, as
/// returned by `bass_replica_status()`: the link, the source's last known state, what never
/// arrived.
#[repr(C)]
pub struct bass_replica_info {
    /// 1 when the source was heard within the mirror's timeout, else 0.
    pub link_up: u32,
    /// Reserved (0).
    pub reserved: u32,
    /// Seconds since the link went up or down (since the mirror started if it never changed).
    pub link_since_s: f64,
    /// The source's epoch the replica follows.
    pub source_epoch: u64,
    /// The newest source frame the mirror heard of.
    pub source_last_frame_index: u64,
    /// Frames the replica published as GAP for chunks that never arrived.
    pub gap_frames_lost: u64,
    /// Of those, frames the source reported as not sent.
    pub gap_frames_source: u64,
    /// Times the replica went into the error state (link silent, or the source failed).
    pub outages: u64,
    /// Messages dropped for lacking the source's signature.
    pub forged_messages: u64,
    /// The source broker's name, NUL terminated.
    pub source: [c_char; BASS_DEVICE_LEN],
    /// The source's last known state (`capturing`, `stopped`, `error`, `gone`, ...), NUL
    /// terminated.
    pub source_state: [c_char; BASS_SOURCE_STATE_LEN],
}

/// Bytes of `bass_replica_info.source_state` (with the NUL).
pub const BASS_SOURCE_STATE_LEN: usize = 32;

fn replica_to_c(r: &ReplicaStatus) -> bass_replica_info {
    let mut out = bass_replica_info {
        link_up: u32::from(r.link_up),
        reserved: 0,
        link_since_s: r.link_since_s,
        source_epoch: r.source_epoch,
        source_last_frame_index: r.source_last_frame_index,
        gap_frames_lost: r.gap_frames_lost,
        gap_frames_source: r.gap_frames_source,
        outages: r.outages,
        forged_messages: r.forged_messages,
        source: [0; BASS_DEVICE_LEN],
        source_state: [0; BASS_SOURCE_STATE_LEN],
    };
    copy_text(&mut out.source, &r.source);
    copy_text(&mut out.source_state, &r.source_state);
    out
}

/// The replica's side of broker `broker` (NULL = "default") when it is a mirror's replica
/// (`bass-bridge mirror --name NAME`): the link to the source, the source's last known state
/// and what never arrived; `bass_status()` on the same name gives the replica port itself.
/// A broker that is not a mirror (a bassd) gives `BASS_ERR_NOT_FOUND`, nothing written.
///
/// # Safety
/// `broker` must be NULL or NUL-terminated; `out_replica` valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_replica_status(
    broker: *const c_char,
    out_replica: *mut bass_replica_info,
) -> bass_result {
    boundary("bass_replica_status", || {
        let out = nonnull_mut(out_replica, "out_replica")?;
        // SAFETY: forwarded caller guarantee.
        let mut client = unsafe { connect(broker) }?;
        let status = client.status()?;
        let Some(r) = status.replica.as_deref() else {
            return Err(Failure::NotFound(
                "this broker is not a replica: it answers Status for its own port (bass_status)".into(),
            ));
        };
        let r = replica_to_c(r);
        // SAFETY: checked non-null; the caller guarantees validity.
        unsafe { out.write(r) };
        Ok(())
    })
}

/// # Safety
/// `broker` must be NULL or NUL-terminated.
unsafe fn connect(broker: *const c_char) -> Result<Client, Failure> {
    let name = if broker.is_null() {
        DEFAULT_NAME
    } else {
        // SAFETY: forwarded caller guarantee.
        unsafe { c_str(broker, "broker") }?
    };
    Ok(Client::connect(name)?)
}

/// Starts an acquisition on broker `broker` (NULL = "default"), interrupting a running one.
/// `channels` 0 means 2. `*out_epoch` (if not NULL) receives the new acquisition's epoch.
///
/// # Safety
/// `broker` must be NULL or NUL-terminated; `device` NUL-terminated; `out_epoch` NULL or
/// valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_acquire(
    broker: *const c_char,
    device: *const c_char,
    sample_rate: u32,
    frames_per_chunk: u32,
    chunks_on_port: u32,
    channels: u32,
    out_epoch: *mut u64,
) -> bass_result {
    boundary("bass_acquire", || {
        // SAFETY: forwarded caller guarantee.
        let device = unsafe { c_str(device, "device") }?;
        // SAFETY: forwarded caller guarantee.
        let mut client = unsafe { connect(broker) }?;
        let req = AcquireRequest {
            device: device.to_owned(),
            sample_rate,
            frames_per_chunk,
            chunks_on_port,
            channels: if channels == 0 { DEFAULT_CHANNELS } else { channels },
            format: None,
            followers: Vec::new(),
        };
        let acquired = client.acquire(&req)?;
        if !out_epoch.is_null() {
            // SAFETY: non-null; the caller guarantees validity.
            unsafe { out_epoch.write(acquired.epoch) };
        }
        Ok(())
    })
}

/// Stops the acquisition of broker `broker` (NULL = "default"); the port keeps its frames
/// and shows `BASS_STATE_STOPPED`. Stopping a stopped broker is not an error.
///
/// # Safety
/// `broker` must be NULL or NUL-terminated.
#[no_mangle]
pub unsafe extern "C" fn bass_stop(broker: *const c_char) -> bass_result {
    boundary("bass_stop", || {
        // SAFETY: forwarded caller guarantee.
        let mut client = unsafe { connect(broker) }?;
        Ok(client.stop()?)
    })
}

fn status_to_c(s: &Status) -> bass_broker_status {
    let mut out = bass_broker_status {
        state: s.state,
        error_code: s.error_code,
        sample_rate: s.sample_rate,
        frames_per_chunk: s.frames_per_chunk,
        chunks_on_port: s.chunks_on_port,
        channels: s.channels,
        epoch: s.epoch,
        last_frame_index: s.last_frame_index,
        xruns: s.xruns,
        gap_frames: s.gap_frames,
        rate_estimate_hz: s.rate_estimate_hz,
        device: [0; BASS_DEVICE_LEN],
        message: [0; BASS_MESSAGE_LEN],
    };
    copy_text(&mut out.device, &s.device);
    copy_text(&mut out.message, &s.message);
    out
}

/// The state of broker `broker` (NULL = "default") and of its current port.
///
/// # Safety
/// `broker` must be NULL or NUL-terminated; `out_status` valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_status(
    broker: *const c_char,
    out_status: *mut bass_broker_status,
) -> bass_result {
    boundary("bass_status", || {
        let out = nonnull_mut(out_status, "out_status")?;
        // SAFETY: forwarded caller guarantee.
        let mut client = unsafe { connect(broker) }?;
        let s = status_to_c(&client.status()?);
        // SAFETY: checked non-null; the caller guarantees validity.
        unsafe { out.write(s) };
        Ok(())
    })
}

/// The capture devices of broker `broker` (NULL = "default"), as lines
/// `"name\tdescription\n"`, NUL terminated, in `buf` (`buf_len` bytes). `*out_len` receives
/// the bytes written including the NUL. If `buf_len` is too small (or `buf` is NULL), nothing
/// is written to `buf`, `*out_len` receives the bytes needed including the NUL, and the
/// result is `BASS_ERR_BUFFER_TOO_SMALL`.
///
/// # Safety
/// `broker` must be NULL or NUL-terminated; `buf` NULL or valid for `buf_len` writes;
/// `out_len` valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_list_devices(
    broker: *const c_char,
    buf: *mut c_char,
    buf_len: usize,
    out_len: *mut usize,
) -> bass_result {
    boundary("bass_list_devices", || {
        let out_len = nonnull_mut(out_len, "out_len")?;
        // SAFETY: forwarded caller guarantee.
        let mut client = unsafe { connect(broker) }?;
        let mut text = String::new();
        for d in client.list_devices()? {
            let clean = |s: &str| s.replace(['\t', '\n', '\r', '\0'], " ");
            text.push_str(&clean(&d.name));
            text.push('\t');
            text.push_str(&clean(&d.description));
            text.push('\n');
        }
        let needed = text.len() + 1;
        if buf.is_null() || buf_len < needed {
            // SAFETY: checked non-null; the caller guarantees validity.
            unsafe { out_len.write(needed) };
            return Err(Failure::Small(format!("the device list needs {needed} bytes; buf_len = {buf_len}")));
        }
        // SAFETY: `buf` is non-null and valid for `buf_len >= needed` bytes (caller guarantee);
        // the source is a distinct Rust allocation.
        unsafe {
            std::ptr::copy_nonoverlapping(text.as_ptr().cast::<c_char>(), buf, text.len());
            buf.add(text.len()).write(0);
            out_len.write(needed);
        }
        Ok(())
    })
}

/// One device of a broker's acquisition (docs/multi-device.md), as returned by
/// `bass_broker_device_info()`: the master is device 0, the followers follow in port channel
/// order.
#[repr(C)]
pub struct bass_device_info {
    /// Its first channel on the port.
    pub first_channel: u32,
    /// Its channels.
    pub channels: u32,
    /// Times it locked (a follower).
    pub locks: u64,
    /// Recovered overruns (the master's: the port's).
    pub xruns: u64,
    /// Times it was lost (unplugged) and reopened.
    pub unplugs: u64,
    /// Frames published with its channels missing (zeros; the master's: the port's GAP frames).
    pub missing_frames: u64,
    /// Frames published while it was not locked.
    pub unaligned_frames: u64,
    /// Its rate against the master's, ppm (0 for the master).
    pub ratio_ppm: f64,
    /// The current alignment error estimate, samples (0 for the master).
    pub error_estimate: f64,
    /// Device name, NUL terminated.
    pub name: [c_char; BASS_DEVICE_LEN],
    /// `master` or `follower`, NUL terminated.
    pub role: [c_char; BASS_DEVICE_STATE_LEN],
    /// `master`, or a follower's `waiting`, `aligning`, `locked` or `lost`, NUL terminated.
    pub state: [c_char; BASS_DEVICE_STATE_LEN],
}

/// Bytes of `bass_device_info.role` and `.state` (with the NUL).
pub const BASS_DEVICE_STATE_LEN: usize = 16;

/// Most devices `bass_acquire_devices()` takes (the broker's limit).
pub const BASS_MAX_DEVICES: usize = 8;

/// Starts an acquisition of several devices on broker `broker` (NULL = "default"),
/// interrupting a running one (docs/multi-device.md): `devices[0]` is the master clock, the
/// others follow it, resampled onto its frames; each has `channels` channels (0 means 2),
/// after the master's on the port. `*out_epoch` (if not NULL) receives the new epoch. One
/// device is `bass_acquire()`; a channel count per device is
/// `bass_acquire_devices_channels()`. A broker that predates several devices gives
/// `BASS_ERR_PROTOCOL`.
///
/// # Safety
/// `broker` must be NULL or NUL-terminated; `devices` valid for `devices_len` reads of
/// NUL-terminated strings; `out_epoch` NULL or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_acquire_devices(
    broker: *const c_char,
    devices: *const *const c_char,
    devices_len: usize,
    sample_rate: u32,
    frames_per_chunk: u32,
    chunks_on_port: u32,
    channels: u32,
    out_epoch: *mut u64,
) -> bass_result {
    boundary("bass_acquire_devices", || {
        // SAFETY: forwarded caller guarantee on `devices`.
        let names = unsafe { device_names(devices, devices_len) }?;
        let counts = vec![channels; names.len()];
        // SAFETY: forwarded caller guarantees.
        unsafe {
            acquire_devices(broker, &names, &counts, sample_rate, frames_per_chunk, chunks_on_port, out_epoch)
        }
    })
}

/// `bass_acquire_devices()` with a channel count per device: `channels[i]` for
/// `devices[i]` (`channels[0]` the master's, 0 meaning 2; a follower's 0 meaning as many as
/// the master's), `devices_len` of each.
///
/// # Safety
/// As `bass_acquire_devices()`; `channels` valid for `devices_len` reads.
#[no_mangle]
pub unsafe extern "C" fn bass_acquire_devices_channels(
    broker: *const c_char,
    devices: *const *const c_char,
    channels: *const u32,
    devices_len: usize,
    sample_rate: u32,
    frames_per_chunk: u32,
    chunks_on_port: u32,
    out_epoch: *mut u64,
) -> bass_result {
    boundary("bass_acquire_devices_channels", || {
        // SAFETY: forwarded caller guarantee on `devices`.
        let names = unsafe { device_names(devices, devices_len) }?;
        let counts_ptr = super::nonnull(channels, "channels")?;
        // SAFETY: `counts_ptr` is valid for `devices_len` reads (caller guarantee), and
        // `devices_len` was checked to be 1..=BASS_MAX_DEVICES by `device_names`.
        let counts = unsafe { std::slice::from_raw_parts(counts_ptr, devices_len) }.to_vec();
        // SAFETY: forwarded caller guarantees.
        unsafe {
            acquire_devices(broker, &names, &counts, sample_rate, frames_per_chunk, chunks_on_port, out_epoch)
        }
    })
}

/// The names of `devices` (1..=[`BASS_MAX_DEVICES`] of them).
///
/// # Safety
/// `devices` valid for `devices_len` reads of NUL-terminated strings (or NULL: refused).
unsafe fn device_names(devices: *const *const c_char, devices_len: usize) -> Result<Vec<String>, Failure> {
    let list = super::nonnull(devices, "devices")?;
    if devices_len == 0 || devices_len > BASS_MAX_DEVICES {
        return Err(Failure::Lib(bassport::Error::InvalidArgument(format!(
            "devices_len = {devices_len} (must be 1..={BASS_MAX_DEVICES})"
        ))));
    }
    let mut names = Vec::with_capacity(devices_len);
    for i in 0..devices_len {
        // SAFETY: `list` is valid for `devices_len` reads (caller guarantee), i < devices_len.
        let p = unsafe { list.add(i).read() };
        if p.is_null() {
            return Err(Failure::NullAt("devices", i));
        }
        // SAFETY: non-null and NUL-terminated (caller guarantee).
        names.push(unsafe { c_str(p, "devices[i]") }?.to_owned());
    }
    Ok(names)
}

/// One Acquire of `names` (the first the master) with `counts[i]` channels each.
///
/// # Safety
/// `broker` NULL or NUL-terminated; `out_epoch` NULL or valid for a write.
unsafe fn acquire_devices(
    broker: *const c_char,
    names: &[String],
    counts: &[u32],
    sample_rate: u32,
    frames_per_chunk: u32,
    chunks_on_port: u32,
    out_epoch: *mut u64,
) -> Result<(), Failure> {
    // SAFETY: forwarded caller guarantee.
    let mut client = unsafe { connect(broker) }?;
    let followers = names[1..]
        .iter()
        .zip(&counts[1..])
        .map(|(d, &channels)| FollowerRequest { device: d.clone(), channels })
        .collect();
    let req = AcquireRequest {
        device: names[0].clone(),
        sample_rate,
        frames_per_chunk,
        chunks_on_port,
        channels: if counts[0] == 0 { DEFAULT_CHANNELS } else { counts[0] },
        format: None,
        followers,
    };
    let acquired = client.acquire(&req)?;
    if !out_epoch.is_null() {
        // SAFETY: non-null; the caller guarantees validity.
        unsafe { out_epoch.write(acquired.epoch) };
    }
    Ok(())
}

fn device_to_c(d: &DeviceStatus) -> bass_device_info {
    let mut out = bass_device_info {
        first_channel: d.first_channel,
        channels: d.channels,
        locks: d.locks,
        xruns: d.xruns,
        unplugs: d.unplugs,
        missing_frames: d.missing_frames,
        unaligned_frames: d.unaligned_frames,
        ratio_ppm: d.ratio_ppm,
        error_estimate: d.error_estimate,
        name: [0; BASS_DEVICE_LEN],
        role: [0; BASS_DEVICE_STATE_LEN],
        state: [0; BASS_DEVICE_STATE_LEN],
    };
    copy_text(&mut out.name, &d.name);
    copy_text(&mut out.role, &d.role);
    copy_text(&mut out.state, &d.state);
    out
}

/// Device `index` (0: the master) of broker `broker`'s acquisition (NULL = "default"): its
/// channels, state, rate against the master, alignment error and counters. An acquisition of
/// one device has device 0 only (the port's own figures); an index past the last device, or a
/// broker that has not acquired yet, gives `BASS_ERR_NOT_FOUND`, nothing written. To list
/// them, call with 0, 1, ... until `BASS_ERR_NOT_FOUND`.
///
/// # Safety
/// `broker` must be NULL or NUL-terminated; `out_info` valid for a write.
#[no_mangle]
pub unsafe extern "C" fn bass_broker_device_info(
    broker: *const c_char,
    index: u32,
    out_info: *mut bass_device_info,
) -> bass_result {
    boundary("bass_broker_device_info", || {
        let out = nonnull_mut(out_info, "out_info")?;
        // SAFETY: forwarded caller guarantee.
        let mut client = unsafe { connect(broker) }?;
        let s = client.status()?;
        let one = [DeviceStatus {
            name: s.device.clone(),
            role: "master".into(),
            channels: s.channels,
            state: "master".into(),
            xruns: s.xruns,
            missing_frames: s.gap_frames,
            ..DeviceStatus::default()
        }];
        let devices: &[DeviceStatus] = match (s.devices.is_empty(), s.epoch) {
            (false, _) => &s.devices,
            (true, 0) => &[],
            (true, _) => &one,
        };
        let Some(d) = devices.get(index as usize) else {
            return Err(Failure::NotFound(format!(
                "device index {index}: the acquisition has {} device(s){}",
                devices.len(),
                if s.epoch == 0 { " (the broker has not acquired yet)" } else { "" }
            )));
        };
        let info = device_to_c(d);
        // SAFETY: checked non-null; the caller guarantees validity.
        unsafe { out.write(info) };
        Ok(())
    })
}

const _: () = assert!(
    std::mem::size_of::<bass_device_info>()
        == 8 + 5 * 8 + 2 * 8 + BASS_DEVICE_LEN + 2 * BASS_DEVICE_STATE_LEN
);
const _: () =
    assert!(std::mem::size_of::<bass_broker_status>() == 24 + 40 + BASS_DEVICE_LEN + BASS_MESSAGE_LEN);
const _: () = assert!(
    std::mem::size_of::<bass_replica_info>() == 8 + 8 + 6 * 8 + BASS_DEVICE_LEN + BASS_SOURCE_STATE_LEN
);
