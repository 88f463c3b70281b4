//! Replica support: a writer that follows another port's frame indices (`bass-bridge mirror`).
//!
//! Kept apart from the broker's create/publish path: these only move `last_frame_index`
//! forward in ways a local device never needs (a start at a given frame, a run of frames
//! lost upstream).

use std::sync::atomic::Ordering::{Relaxed, Release};

use super::{wake, write_entry, ChunkMeta, Stamp, Writer};
use crate::error::{Error, Result};
use crate::format::{self, State};
use crate::ring::{Ring, Source};
use crate::sys;

impl Writer {
    /// Starts an empty port at frame `first_frame`: the next chunk published gets that index.
    ///
    /// Only on a port that has published nothing yet (`last_frame_index == 0`), and
    /// `first_frame` must start a chunk (`(first_frame - 1) % nFPC == 0`), so that chunk
    /// `c` keeps frames `c*nFPC+1 ..= (c+1)*nFPC` as in the source. Frames before it, which
    /// this port never had, count as **lost** for every reader (`get_audio_data`, views,
    /// `chunk_info`), never as zero frames: a reader at frame 1 gets `n = 0`,
    /// `loss = first_frame - 1` and `nfr = first_frame`, then the frames published from there
    /// (see [`Ring::start_at`]: the write intent keeps a floor of `first_frame - 1 + nFOP`
    /// until the window has passed `first_frame`).
    ///
    /// ```
    /// # use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-start-at-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// # let path = dir.join("bass-doc.port");
    /// let geometry = Geometry { channels: 1, sample_rate: 48000, frames_per_chunk: 4, chunks_on_port: 8 };
    /// let mut w = Writer::create_at(&path, &PortParams { geometry, device: "replica".into(), group: None })?;
    /// w.start_at(9)?; // chunk 3 of the source
    /// let port = Port::open_path(&path)?;
    /// let (mut out, mut nfr) = (vec![0; 16], 1);
    /// let r = port.get_audio_data(16, &mut nfr, &mut [&mut out])?;
    /// assert_eq!((r.frames, r.loss, nfr), (0, 8, 9)); // frames 1..=8: lost, not zeros
    /// w.publish(Source::Interleaved(&[1, 2, 3, 4]), ChunkMeta::default())?;
    /// let r = port.get_audio_data(16, &mut nfr, &mut [&mut out])?;
    /// assert_eq!((r.frames, r.loss, &out[..4]), (4, 0, &[1, 2, 3, 4][..]));
    /// # w.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn start_at(&mut self, first_frame: u64) -> Result<()> {
        let nfpc = u64::from(self.geometry.frames_per_chunk);
        let h = self.mapping.header();
        let lfi = h.last_frame_index.load(Relaxed);
        if lfi != 0 {
            return Err(Error::InvalidArgument(format!(
                "start_at({first_frame}) on a port that already published frame {lfi}"
            )));
        }
        if first_frame == 0 || (first_frame - 1) % nfpc != 0 || first_frame > format::MAX_FRAME_INDEX {
            return Err(Error::InvalidArgument(format!(
                "start frame {first_frame} does not start a chunk of {nfpc} frames (1, {}, {}, ...)",
                nfpc + 1,
                2 * nfpc + 1
            )));
        }
        let ring = Ring {
            last_frame_index: &h.last_frame_index,
            write_intent: &h.write_intent,
            samples: self.mapping.samples(&self.layout, self.geometry.channels),
            frames_on_port: self.layout.frames_on_port,
        };
        ring.start_at(first_frame);
        h.heartbeat_mono_ns.store(sys::monotonic_ns(), Relaxed);
        wake(h);
        Ok(())
    }

    /// Moves on to frame `first` without publishing the frames before it: every frame before
    /// `first` that readers could still read (the ones in the window and the unpublished ones
    /// after it) counts as **lost** for every reader, exactly as frames a writer overtook. The
    /// next chunk published is the one holding `first` (its frames before `first` are lost too).
    /// A replay uses it to give back a recording's losses at their frame indices: a reader
    /// keeping up sees `loss = first - nfr` at the same place as the recorder did. Returns the
    /// new last frame index. `first` must be after the last frame published; `first ==
    /// last + 1` does nothing.
    ///
    /// ```
    /// # use bassport::{ChunkMeta, Geometry, Port, PortParams, Source, Writer};
    /// # let dir = std::env::temp_dir().join(format!("bass-doc-skip-to-{}", std::process::id()));
    /// # std::fs::create_dir_all(&dir).unwrap();
    /// # let path = dir.join("bass-doc.port");
    /// let geometry = Geometry { channels: 1, sample_rate: 48000, frames_per_chunk: 4, chunks_on_port: 8 };
    /// let mut w = Writer::create_at(&path, &PortParams { geometry, device: "replay".into(), group: None })?;
    /// let port = Port::open_path(&path)?;
    /// let (mut out, mut nfr) = (vec![0; 4], 1);
    /// w.publish(Source::Interleaved(&[1, 2, 3, 4]), ChunkMeta::default())?;
    /// assert_eq!(port.get_audio_data(4, &mut nfr, &mut [&mut out])?.frames, 4);
    /// w.skip_to(15)?; // frames 5..=14 lost; the next chunk is 13..=16
    /// w.publish(Source::Interleaved(&[0, 0, 15, 16]), ChunkMeta::default())?;
    /// let r = port.get_audio_data(4, &mut nfr, &mut [&mut out])?;
    /// assert_eq!((r.frames, r.loss, nfr), (0, 10, 15)); // one loss of 10 frames, at once
    /// let r = port.get_audio_data(4, &mut nfr, &mut [&mut out])?;
    /// assert_eq!((r.frames, &out[..2]), (2, &[15, 16][..]));
    /// # w.remove()?;
    /// # std::fs::remove_dir_all(&dir).ok();
    /// # Ok::<(), bassport::Error>(())
    /// ```
    pub fn skip_to(&mut self, first: u64) -> Result<u64> {
        let nfpc = u64::from(self.geometry.frames_per_chunk);
        let h = self.mapping.header();
        let lfi = h.last_frame_index.load(Relaxed);
        if first <= lfi || first > format::MAX_FRAME_INDEX {
            return Err(Error::InvalidArgument(format!(
                "skip_to({first}): the port has published frame {lfi}; give a later frame (at most {})",
                format::MAX_FRAME_INDEX
            )));
        }
        if first == lfi + 1 {
            return Ok(lfi);
        }
        let ring = Ring {
            last_frame_index: &h.last_frame_index,
            write_intent: &h.write_intent,
            samples: self.mapping.samples(&self.layout, self.geometry.channels),
            frames_on_port: self.layout.frames_on_port,
        };
        let last = ring.skip_to(lfi, first, nfpc);
        h.heartbeat_mono_ns.store(sys::monotonic_ns(), Relaxed);
        wake(h);
        Ok(last)
    }

    /// Publishes `frames` zero-filled GAP frames standing for frames lost before they reached
    /// this writer (upstream of a replica, or on the network). They are counted in
    /// `gap_frames` and in `lost_upstream_frames`. Returns the new last frame index.
    ///
    /// `frames` must be a whole number of chunks. A gap longer than the window is published
    /// as one window of zeros whose frame indices jump to the gap's end, so its cost is at
    /// most one window whatever its length; readers count the frames they could not read as
    /// loss, exactly as for a gap written chunk by chunk.
    pub fn publish_lost(&mut self, frames: u64, meta: ChunkMeta) -> Result<u64> {
        let nfpc = u64::from(self.geometry.frames_per_chunk);
        if frames % nfpc != 0 {
            return Err(Error::InvalidArgument(format!(
                "a gap of {frames} frames is not a whole number of {nfpc}-frame chunks"
            )));
        }
        let lfi = self.last_frame_index();
        let end = lfi.checked_add(frames).filter(|&e| e <= format::MAX_FRAME_INDEX).ok_or_else(|| {
            Error::InvalidArgument(format!("a gap of {frames} frames after {lfi} passes the limit"))
        })?;
        let fop = self.layout.frames_on_port;
        let meta = ChunkMeta { flags: meta.flags | format::chunk_flags::GAP, ..meta };
        if frames <= fop {
            let mut last = lfi;
            while last < end {
                last = self.publish(Source::Zeros, meta)?;
                self.header().lost_upstream_frames.fetch_add(nfpc, Relaxed);
            }
            return Ok(last);
        }
        // Longer than the window: write one window of zeros as frames end-nFOP+1 ..= end in
        // one publish. The intent (= end) is announced first, so every old frame
        // (<= lfi <= end - nFOP) is condemned before its slot is touched, and readers lapped
        // by the jump count what they missed as loss. A start's intent floor
        // (first - 1 + nFOP <= lfi + nFOP < end) is below `end`, so `publish` announces `end`.
        let h = self.mapping.header();
        let from = end - fop;
        let cop = u64::from(self.geometry.chunks_on_port);
        let table = self.mapping.chunk_table(&self.layout, self.geometry.chunks_on_port);
        let ext = self.mapping.chunk_ext(&self.layout, self.geometry.chunks_on_port);
        let ring = Ring {
            last_frame_index: &h.last_frame_index,
            write_intent: &h.write_intent,
            samples: self.mapping.samples(&self.layout, self.geometry.channels),
            frames_on_port: fop,
        };
        let now_mono = sys::monotonic_ns();
        let mono = if meta.mono_ns == 0 { now_mono } else { meta.mono_ns };
        let real = if meta.realtime_ns == 0 { sys::realtime_ns() } else { meta.realtime_ns };
        let channels = self.geometry.channels as usize;
        let last = ring.publish(from, fop as usize, channels, &Source::Zeros, || {
            for k in 0..cop {
                let first = from + k * nfpc + 1;
                let slot = (((from / nfpc) + k) % cop) as usize;
                let stamp = Stamp { mono, real, meta: &meta };
                write_entry(&table[slot], ext.map(|x| &x[slot]), first, stamp, nfpc as u32);
            }
        });
        h.chunks_published.fetch_add(cop, Relaxed);
        h.gap_frames.fetch_add(frames, Relaxed);
        h.lost_upstream_frames.fetch_add(frames, Relaxed);
        h.heartbeat_mono_ns.store(now_mono, Relaxed);
        if h.state.load(Relaxed) == State::Idle as u32 {
            h.state.store(State::Capturing as u32, Release);
        }
        wake(h);
        self.check_intact()?;
        Ok(last)
    }

    /// Counts `n` frames lost upstream that were published by other means (for example a
    /// source's own GAP chunk that the replica copies as it is).
    pub fn add_lost_upstream(&self, n: u64) {
        self.header().lost_upstream_frames.fetch_add(n, Relaxed);
    }
}
