//! The chunk path of [`Core`]: the bounds, the followed instance, the replica (made anew,
//! rate-limited, for a new stream), the frame checks (late, too far ahead) and the write.

use bassport::format::error_code;
use bassport::{Geometry, PortParams, State, Writer};

use super::{
    held, Core, Outcome, AHEAD_MARGIN_NS, RECREATIONS_PER_MINUTE, RECREATION_INTERVAL_NS, RETRY_NS, SEC,
};
use crate::clock::ClockMap;
use crate::mirror::bounds::Holder;
use crate::mirror::replica::{publish, Replica};
use crate::text::escape;
use crate::wire;

impl Core {
    /// One chunk.
    pub fn on_chunk(&mut self, c: &wire::Chunk, now: u64, clock: Option<ClockMap>) -> Outcome {
        let h = c.header;
        let geometry = match self.check_bounds(&h, now) {
            Ok(g) => g,
            Err(o) => return o,
        };
        if let Some(o) = self.check_instance(&h, now) {
            return o;
        }
        let new_replica = match self.replica_for(&h, geometry, now) {
            Ok(new) => new,
            Err(o) => return o,
        };
        let Some(r) = self.replica.as_mut() else { return Outcome::Failed };
        if h.first_frame < r.expected {
            self.st.late_or_duplicate += 1;
            self.follow(h.instance, now);
            return Outcome::LateOrDuplicate;
        }
        if !new_replica && self.too_far_ahead(&h, now, clock) {
            return Outcome::FarFrame;
        }
        self.follow(h.instance, now);
        self.refuse_pending_state(now);
        self.write_chunk(c, now, clock, new_replica)
    }

    /// The chunk's geometry, or [`Outcome::Invalid`] (counted, logged) if it is outside the
    /// mirror's bounds.
    fn check_bounds(&mut self, h: &wire::Header, now: u64) -> Result<Geometry, Outcome> {
        let geometry = Geometry {
            channels: u32::from(h.channels),
            sample_rate: h.sample_rate,
            frames_per_chunk: h.frames,
            chunks_on_port: h.chunks_on_port,
        };
        if let Err(why) = self.bounds.check(&geometry, Holder::Mirror) {
            self.st.invalid_messages += 1;
            if self.replica.is_none() {
                self.st.error = Some(format!("cannot make the replica for this source: {why}"));
            }
            if let Some(n) = self.logs.invalid.allow(now) {
                tracing::warn!(
                    instance = format!("{:016x}", h.instance),
                    "refused a chunk message: {why}{}",
                    held(n)
                );
            }
            return Err(Outcome::Invalid);
        }
        Ok(geometry)
    }

    /// [`Outcome::OtherSource`] for a chunk of another instance while the followed one is
    /// heard; a chunk of the followed instance renews it.
    fn check_instance(&mut self, h: &wire::Header, now: u64) -> Option<Outcome> {
        // One instance at a time: another one is a second source while the followed is heard.
        match self.followed {
            Some((id, _)) if id != h.instance && self.followed_heard(now) => {
                self.st.refused_other_source += 1;
                self.two_sources(id, h.instance, now);
                return Some(Outcome::OtherSource);
            }
            Some((id, _)) if id == h.instance => {
                self.followed = Some((id, now));
                self.last_heard_ns = now;
            }
            _ => {}
        }
        None
    }

    /// Makes the replica for a chunk of a new stream (`Ok(true)`), keeps it for the same
    /// stream (`Ok(false)`, also from a new instance after the followed one went silent), or
    /// the outcome if it was not made.
    fn replica_for(&mut self, h: &wire::Header, geometry: Geometry, now: u64) -> Result<bool, Outcome> {
        let same = self.replica.as_ref().is_some_and(|r| r.source_epoch == h.epoch && r.geometry == geometry);
        let switching = self.followed.is_some_and(|(id, _)| id != h.instance);
        if !same {
            // A new acquisition upstream (or the first chunk): a new replica port, rate-limited.
            if let Some(o) = self.make_replica(h, geometry, now) {
                return Err(o);
            }
            return Ok(true);
        }
        if switching {
            tracing::info!(
                instance = format!("{:016x}", h.instance),
                "new serve instance (the one followed went silent), same epoch: the port is kept"
            );
            if let Some(r) = self.replica.as_mut() {
                r.last_source_lost = 0;
            }
        }
        Ok(false)
    }

    /// The chunk is ahead by more than the time allows (plus a window and a margin): it is
    /// refused (counted, logged), so that one forged chunk far ahead cannot make every real
    /// one "late". The time: since the last chunk arrived, or — when the clock estimate says
    /// where the source's clock is now — since the last chunk's first frame was captured (a
    /// backlog of late chunks on a congested link must not make the next fresh one look too
    /// far ahead).
    fn too_far_ahead(&mut self, h: &wire::Header, now: u64, clock: Option<ClockMap>) -> bool {
        let Some(r) = self.replica.as_ref() else { return false };
        let rate = u128::from(r.geometry.sample_rate);
        let margin = u128::from(AHEAD_MARGIN_NS) * rate / u128::from(SEC)
            + u128::from(r.writer.layout().frames_on_port);
        let elapsed = now.saturating_sub(r.last_chunk_ns);
        let by_arrival = u128::from(elapsed) * rate / u128::from(SEC);
        let by_clock = match clock.map(|m| m.offset_ns) {
            Some(off) if r.last_mono_ns != 0 => {
                let source_now = i128::from(now) + i128::from(off);
                let since = (source_now - i128::from(r.last_mono_ns)).max(0) as u128;
                // Frames since the last chunk's first frame, less that chunk's own.
                (since * rate / u128::from(SEC)).saturating_sub(u128::from(h.frames))
            }
            _ => 0,
        };
        let allowed = by_arrival.max(by_clock) + margin;
        if u128::from(h.first_frame - r.expected) > allowed {
            self.st.refused_far_frames += 1;
            if let Some(n) = self.logs.far.allow(now) {
                tracing::warn!(
                    "refused a chunk at frame {} (expected {}): further ahead than the time since the last \
                     chunk allows ({:.1} s since it arrived){}",
                    h.first_frame,
                    r.expected,
                    elapsed as f64 / 1e9,
                    held(n)
                );
            }
            return true;
        }
        false
    }

    /// A chunk of the followed stream: a state that arrived before it is not the source's
    /// (counted, logged, dropped).
    fn refuse_pending_state(&mut self, now: u64) {
        if let Some(p) = self.pending_state.take() {
            self.st.refused_states += 1;
            if let Some(n) = self.logs.states.allow(now) {
                tracing::warn!(
                    "ignored a source state {:?}: the source's chunks went on after it{}",
                    p.state.state,
                    held(n)
                );
            }
        }
    }

    /// Publishes the chunk into the replica; a replica that cannot be written is dropped (made
    /// again on a later chunk).
    fn write_chunk(
        &mut self,
        c: &wire::Chunk,
        now: u64,
        clock: Option<ClockMap>,
        new_replica: bool,
    ) -> Outcome {
        let h = c.header;
        let Some(r) = self.replica.as_mut() else { return Outcome::Failed };
        match publish(r, &mut self.st, c, &mut self.samples, now, clock) {
            Ok(gap) => {
                // When it was queued (not its first frame's time, a chunk earlier or more).
                self.last_stamp = (h.send_mono_ns != 0).then_some((h.send_mono_ns, now));
                if self.in_error {
                    r.writer.set_state(State::Capturing, error_code::NONE, "");
                    self.in_error = false;
                    tracing::info!("source {:?} back: replica capturing again", self.st.source);
                }
                Outcome::Applied { gap, new_replica }
            }
            Err(e) => {
                self.st.error = Some(format!("writing the replica: {e}"));
                if let Some(n) = self.logs.create.allow(now) {
                    tracing::error!("writing the replica: {e}{}", held(n));
                }
                // A replica that cannot be written is made again on a later chunk.
                self.replica = None;
                self.failed_at = Some(now);
                Outcome::Failed
            }
        }
    }

    /// Makes the replica for a chunk of a new stream; `Some(outcome)` if it was not made.
    fn make_replica(&mut self, h: &wire::Header, geometry: Geometry, now: u64) -> Option<Outcome> {
        while self.creations.front().is_some_and(|&t| now.saturating_sub(t) >= 60 * SEC) {
            self.creations.pop_front();
        }
        let too_soon = self.creations.back().is_some_and(|&t| now.saturating_sub(t) < RECREATION_INTERVAL_NS);
        if too_soon || self.creations.len() >= RECREATIONS_PER_MINUTE {
            self.st.refused_epochs += 1;
            if let Some(n) = self.logs.epochs.allow(now) {
                tracing::warn!(
                    epoch = h.epoch,
                    instance = format!("{:016x}", h.instance),
                    "refused a new source epoch: more than one new replica a second or {RECREATIONS_PER_MINUTE} a minute{}",
                    held(n)
                );
            }
            return Some(Outcome::RefusedEpoch);
        }
        if self.failed_at.is_some_and(|t| now.saturating_sub(t) < RETRY_NS) {
            return Some(Outcome::Failed);
        }
        let params = PortParams {
            geometry: geometry.clone(),
            device: format!("bass-bridge mirror of {} (source epoch {})", self.st.source, h.epoch),
            group: self.group,
        };
        // The old replica stays until the new one is in place (it is superseded then).
        let made = Writer::create_at(&self.port_path, &params).and_then(|mut w| {
            w.start_at(h.first_frame)?;
            Ok(w)
        });
        let writer = match made {
            Ok(w) => w,
            Err(e) => {
                let msg = format!("cannot make the replica port {}: {e}", self.port_path.display());
                if let Some(n) = self.logs.create.allow(now) {
                    tracing::error!("{msg}; trying again on a later message{}", held(n));
                }
                self.st.error = Some(escape(&msg));
                self.failed_at = Some(now);
                return Some(Outcome::Failed);
            }
        };
        self.failed_at = None;
        self.creations.push_back(now);
        self.st.replica_recreations += 1;
        if self.st.error.as_deref().is_some_and(|e| e.starts_with("cannot make") || e.starts_with("writing"))
        {
            self.st.error = None;
        }
        tracing::info!(epoch = h.epoch, replica_epoch = writer.epoch(), first = h.first_frame, "new replica");
        self.st.replica_epoch = writer.epoch();
        self.st.source_epoch = h.epoch;
        self.in_error = false;
        self.pending_state = None;
        self.replica = Some(Replica {
            writer,
            source_epoch: h.epoch,
            geometry,
            expected: h.first_frame,
            last_source_lost: h.source_lost,
            last_chunk_ns: now,
            last_mono_ns: 0,
            anchor: None,
        });
        None
    }

    fn two_sources(&mut self, followed: u64, other: u64, now: u64) {
        self.other = Some((other, now));
        let ids = vec![format!("{followed:016x}"), format!("{other:016x}")];
        let msg = format!(
            "two sources named {:?} on this network: serve instances {} (followed) and {} \
             (refused); give one of them another --name",
            self.st.source, ids[0], ids[1]
        );
        if self.st.two_sources != ids {
            self.st.two_sources = ids;
            if let Some(r) = self.replica.as_ref().filter(|_| !self.in_error) {
                // Said on the port too, without changing its state: the followed source goes on.
                r.writer.set_state(r.writer.state(), error_code::NONE, &escape(&msg));
            }
        }
        self.st.error = Some(escape(&msg));
        if let Some(n) = self.logs.two.allow(now) {
            tracing::error!("{}{}", escape(&msg), held(n));
        }
    }
}
