//! What a port says about itself: the chunk holding a frame (timestamps, flags) and the
//! whole state (`bass_port_info`).

use std::sync::atomic::{fence, Ordering::Acquire, Ordering::Relaxed};

use super::{ChunkInfo, Port, PortInfo};
use crate::error::{Error, Result};
use crate::format::{self, State};
use crate::sys;

impl Port {
    pub(super) fn message(&self) -> String {
        format::read_text(&self.header().message)
    }

    /// Timestamps and flags of the chunk that holds `frame`.
    ///
    /// ```
    /// use bassport::format::chunk_flags;
    /// use bassport::{ChunkMeta, Error, Geometry, Port, PortParams, Source, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-chunk-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// # let path = dir.join("bass-doc.port");
    /// let geometry = Geometry { channels: 1, sample_rate: 8000, frames_per_chunk: 2, chunks_on_port: 4 };
    /// let mut w = Writer::create_at(&path, &PortParams { geometry, device: "doc".into(), group: None })?;
    /// let late = ChunkMeta { mono_ns: 1_000, realtime_ns: 2_000, flags: chunk_flags::LATE, ..ChunkMeta::default() };
    /// w.publish(Source::Interleaved(&[1, 2]), late)?;
    /// let port = Port::open_path(&path)?;
    /// let c = port.chunk_info(2)?;
    /// assert_eq!((c.first_frame, c.frames, c.mono_ns, c.flags), (1, 2, 1_000, chunk_flags::LATE));
    /// assert_eq!(c.bound(), None); // published without a bound
    /// let bounded = ChunkMeta { mono_ns: 3_000, bound_ns: Some(40_000), missing_channels: 1, ..late };
    /// w.publish(Source::Interleaved(&[0, 0]), bounded)?;
    /// let c = port.chunk_info(3)?;
    /// assert_eq!((c.first_frame, c.bound(), c.missing_channels), (3, Some(40_000), 1));
    /// assert!(matches!(port.chunk_info(5), Err(Error::FrameNotYet { frame: 5, last: 4 })));
    /// # drop(port);
    /// # w.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn chunk_info(&self, frame: u64) -> Result<ChunkInfo> {
        self.check_size()?;
        let lfi = self.last_frame_index();
        self.check_intact()?;
        let lfi = lfi?;
        let ring = self.ring();
        let oldest = (lfi + 1).saturating_sub(self.layout.frames_on_port).max(1);
        if frame > lfi {
            return Err(Error::FrameNotYet { frame, last: lfi });
        }
        if frame < oldest {
            return Err(Error::FrameLost { frame, oldest });
        }
        let nfpc = u64::from(self.geometry.frames_per_chunk);
        let chunk = (frame - 1) / nfpc;
        let table = self.mapping.chunk_table(&self.layout, self.geometry.chunks_on_port);
        let e = &table[(chunk % u64::from(self.geometry.chunks_on_port)) as usize];
        let slot = (chunk % u64::from(self.geometry.chunks_on_port)) as usize;
        let ext = self.mapping.chunk_ext(&self.layout, self.geometry.chunks_on_port).map(|x| &x[slot]);
        let info = ChunkInfo {
            first_frame: e.first_frame.load(Relaxed),
            frames: e.frames.load(Relaxed),
            mono_ns: e.mono_ns.load(Relaxed),
            realtime_ns: e.realtime_ns.load(Relaxed),
            flags: e.flags.load(Relaxed),
            bound_ns: ext.map_or(format::BOUND_UNKNOWN, |x| x.bound_ns.load(Relaxed)),
            missing_channels: ext.map_or(0, |x| x.missing_channels.load(Relaxed)),
            unaligned_channels: ext.map_or(0, |x| x.unaligned_channels.load(Relaxed)),
        };
        let ext_first = ext.map(|x| x.first_frame.load(Relaxed));
        fence(Acquire);
        let intact = ring.first_intact(self.header().write_intent.load(Relaxed));
        self.check_intact()?;
        if frame < intact {
            return Err(Error::FrameLost { frame, oldest: intact });
        }
        if info.first_frame != chunk * nfpc + 1 || u64::from(info.frames) != nfpc {
            return Err(Error::Corrupt(format!(
                "chunk table entry for frame {frame} says first frame {}, {} frames",
                info.first_frame, info.frames
            )));
        }
        if let Some(x) = ext_first.filter(|&x| x != info.first_frame) {
            return Err(Error::Corrupt(format!(
                "chunk extension row for frame {frame} says first frame {x}, the chunk table {}",
                info.first_frame
            )));
        }
        Ok(info)
    }

    /// A snapshot of the header.
    pub fn info(&self) -> Result<PortInfo> {
        self.check_size()?;
        let h = self.header();
        let pid = h.writer_pid.load(Relaxed);
        let info = PortInfo {
            geometry: self.geometry.clone(),
            frames_on_port: self.layout.frames_on_port,
            last_frame_index: h.last_frame_index.load(Acquire),
            epoch: self.epoch,
            state: State::from_u32(h.state.load(Acquire)),
            error_code: h.error_code.load(Relaxed),
            message: self.message(),
            device: format::read_text(&h.device),
            xruns: h.xruns.load(Relaxed),
            gap_frames: h.gap_frames.load(Relaxed),
            lost_upstream_frames: h.lost_upstream_frames.load(Relaxed),
            chunks_published: h.chunks_published.load(Relaxed),
            rate_estimate_hz: h.rate_estimate_mhz.load(Relaxed) as f64 / 1000.0,
            writer_pid: pid,
            writer_alive: self.writer_alive(sys::monotonic_ns),
            started_mono_ns: h.started_mono_ns.load(Relaxed),
            heartbeat_mono_ns: h.heartbeat_mono_ns.load(Relaxed),
            version_minor: self.version_minor,
        };
        self.check_intact()?;
        Ok(info)
    }
}
