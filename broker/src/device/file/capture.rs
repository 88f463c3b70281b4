//! The replay as a capture device: each read waits until the chunk's recorded time and
//! gives the chunk as recorded (its frames, GAP zeros, losses and flags).

use bassport::sys::monotonic_ns;

use super::{FileDevice, NS_PER_MS, PENDING_SLICE_NS};
use crate::device::{sleep_until, Capture, ReadEvent, RecordedChunk, StopSignal};

impl Capture for FileDevice {
    fn start(&mut self) -> Result<(), String> {
        self.start_ns = monotonic_ns();
        Ok(())
    }

    fn read(&mut self, out: &mut [i32], _max_frames: usize, stop: &StopSignal) -> ReadEvent {
        let (p0, readable_from, c) = match self.ready.take() {
            Some(r) => r,
            None => match self.prepare() {
                Some(r) => r,
                None => return self.end(stop),
            },
        };
        let due = self.due_ns(p0 + self.nfpc);
        let slice_end = monotonic_ns() + PENDING_SLICE_NS;
        if due > slice_end {
            // A long wait (the time of a recorded loss): report in between that the device is
            // alive, so the stall watchdog does not take the silence for a dead device.
            self.ready = Some((p0, readable_from, c));
            return if sleep_until(slice_end, stop) { ReadEvent::Pending } else { ReadEvent::Stopped };
        }
        if !sleep_until(due, stop) {
            return ReadEvent::Stopped;
        }
        let woke = monotonic_ns();
        self.last_due = due;
        if let Err(e) = self.fill_chunk(p0, out) {
            return self.failed(&e);
        }
        let span = due - self.due_ns(p0);
        let late = woke.saturating_sub(due) > span.max(NS_PER_MS);
        let (meta, zeros) = self.meta(p0, &c, late);
        let in_file = c.gap + c.data + c.late_lost;
        self.done.frames += in_file;
        if zeros {
            self.done.gap += in_file;
        }
        self.done.padded += c.after;
        self.done.first.get_or_insert(readable_from);
        self.done.last = p0 + self.nfpc - 1 - c.after;
        ReadEvent::Chunk(RecordedChunk { first_frame: p0, readable_from, zeros, meta })
    }

    fn format_name(&self) -> &'static str {
        "S32_LE"
    }
}
