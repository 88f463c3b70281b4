//! The replica port and how one chunk of the followed stream is written into it: samples
//! straight from the message's planar layout into the writer's planar rings (one reused
//! buffer, no allocation per chunk), flags as the source had them ([`wire::port_flags`]),
//! timestamps mapped to the local clock.

use bassport::format::chunk_flags;
use bassport::{ChunkMeta, Geometry, Source, Writer};

use super::status::MirrorStatus;
use crate::clock::ClockMap;
use crate::wire;

const SEC: u64 = 1_000_000_000;

/// The replica and what it follows.
pub struct Replica {
    /// The replica port.
    pub writer: Writer,
    /// Source epoch it mirrors.
    pub source_epoch: u64,
    /// Its geometry (the source's).
    pub geometry: Geometry,
    /// The next frame expected.
    pub expected: u64,
    /// The source's `source_lost` in the last chunk applied.
    pub last_source_lost: u64,
    /// When the last chunk was applied (local ns).
    pub last_chunk_ns: u64,
    /// Its first frame's capture time (source CLOCK_MONOTONIC ns; 0 = not stamped).
    pub last_mono_ns: u64,
    /// First applied chunk (frame, source mono ns) for the rate estimate.
    pub anchor: Option<(u64, u64)>,
}

/// Publishes a chunk of the followed stream at or after the expected frame; returns the
/// frames published as lost before it. `samples` is the mirror's reused sample buffer.
///
/// The replica's flags are the source chunk's ([`wire::port_flags`]: LATE, DISCONTINUITY,
/// GAP as they were; DISCONTINUITY after a SOURCE_LOSS), plus TIME_ESTIMATED always: its
/// timestamps are the source's mapped to the local clock by the clock estimate (or the
/// arrival time, without one), docs/network.md, "Clocks".
pub fn publish(
    r: &mut Replica,
    st: &mut MirrorStatus,
    c: &wire::Chunk,
    samples: &mut Vec<i32>,
    now: u64,
    clock: Option<ClockMap>,
) -> bassport::Result<u64> {
    let h = c.header;
    let mono = match clock {
        Some(m) if h.mono_ns != 0 => (h.mono_ns as i64).saturating_sub(m.offset_ns).max(1) as u64,
        _ => 0,
    };
    // The mapped stamp is as good as the source's stamp and the map together; without a map
    // (the arrival time) or a source bound, nothing bounds it.
    let bound_ns = match clock {
        Some(m) if mono != 0 && h.bound_ns != bassport::format::BOUND_UNKNOWN => {
            Some(h.bound_ns.saturating_add(m.uncertainty_ns).min(bassport::format::BOUND_UNKNOWN - 1))
        }
        _ => None,
    };
    let missing = h.first_frame - r.expected;
    if missing > 0 {
        // The source's cumulative count says how many of them it never sent.
        let from_source = h.source_lost.saturating_sub(r.last_source_lost).min(missing);
        r.writer.publish_lost(
            missing,
            ChunkMeta {
                mono_ns: 0,
                realtime_ns: 0,
                flags: chunk_flags::TIME_ESTIMATED,
                ..ChunkMeta::default()
            },
        )?;
        st.gap_frames_lost += missing;
        st.gap_frames_source += from_source;
    }
    r.last_source_lost = h.source_lost;
    let flags = wire::port_flags(h.flags) | chunk_flags::TIME_ESTIMATED;
    let meta = ChunkMeta {
        mono_ns: mono,
        realtime_ns: h.realtime_ns,
        flags,
        bound_ns,
        missing_channels: h.missing_channels,
        unaligned_channels: h.unaligned_channels,
    };
    if c.is_gap() {
        r.writer.publish(Source::Zeros, meta)?;
    } else {
        // Planar on the wire and in the port: one slice per channel of the decoded buffer.
        c.planar_into(samples);
        let mut planes: [&[i32]; wire::MAX_CHANNELS as usize] = [&[]; wire::MAX_CHANNELS as usize];
        for (p, s) in planes.iter_mut().zip(samples.chunks_exact(h.frames as usize)) {
            *p = s;
        }
        r.writer.publish(Source::Planar(&planes[..usize::from(h.channels)]), meta)?;
    }
    r.expected = h.first_frame + u64::from(h.frames);
    r.last_chunk_ns = now;
    r.last_mono_ns = h.mono_ns;
    st.chunks_written += 1;
    // A chunk is the source capturing, whatever its last state message said.
    st.source_state = crate::net::BridgeState::Capturing;
    st.source_last_frame_index = st.source_last_frame_index.max(r.expected - 1);
    // The replica's rate estimate: the source's frames over the source's clock, from the
    // first chunk on (a value far from the nominal rate is a bad stamp, not a rate).
    if h.mono_ns != 0 {
        match r.anchor {
            None => r.anchor = Some((h.first_frame, h.mono_ns)),
            Some((f0, m0)) if h.mono_ns > m0 + SEC => {
                let hz = (h.first_frame - f0) as f64 * 1e9 / (h.mono_ns - m0) as f64;
                let nominal = f64::from(r.geometry.sample_rate);
                if (hz - nominal).abs() < nominal * 0.01 {
                    r.writer.set_rate_estimate(hz);
                }
            }
            Some(_) => {}
        }
    }
    Ok(missing)
}
