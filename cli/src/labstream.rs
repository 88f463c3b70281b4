//! What a port looks like as a lab stream, said once for `bass lsl` (live, [`crate::lsl`]) and
//! `bass record --format xdf` (recorded, [`crate::record::xdf_out`]), so that a lab sees the
//! same thing in both: the stream's `desc` elements, its source id, each sample's timestamp,
//! which frames are zero-filled, and the JSON of a loss marker.

use bassport::format::chunk_flags;
use bassport::Geometry;

/// The cause of a loss marker: frames the reader lost to the port's window (not in the stream).
pub const OVERRUN: &str = "overrun";
/// The cause of a loss marker: frames the broker zero-filled (in the stream, as zeros).
pub const GAP: &str = "gap";

/// This host's name (empty if /proc does not say).
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().to_owned()).unwrap_or_default()
}

/// The audio stream's source id, `bass:HOST:BROKER` (the marker stream's adds `:loss`).
pub fn source_id(host: &str, broker: &str) -> String {
    format!("bass:{host}:{broker}")
}

/// The audio stream's name for broker `broker`: `bass` for "default", else `bass-BROKER`
/// (the marker stream's is [`marker_stream_name`]).
pub fn stream_name(broker: &str) -> String {
    if broker == "default" {
        "bass".into()
    } else {
        format!("bass-{broker}")
    }
}

/// The marker stream's name: `STREAM-loss`.
pub fn marker_stream_name(stream: &str) -> String {
    format!("{stream}-loss")
}

/// The marker stream's `desc`: the audio stream it speaks of.
pub fn marker_desc(stream: &str) -> Vec<(String, String)> {
    vec![("bass/audio_stream".to_owned(), stream.to_owned())]
}

/// What the audio stream's stamps are, for its `desc`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Clock {
    /// Live: LSL's clock (`bass lsl`).
    Lsl,
    /// Recorded: the recording host's CLOCK_MONOTONIC in seconds (`bass record --format xdf`).
    Monotonic,
}

/// The audio stream's `desc` as `(path, value)` elements in order (`a/b` is element `b` in
/// `a`; a path part `name#key` is an element `name`, `#key` only telling siblings apart):
/// the broker, the host, the epoch, the geometry, the frame indexing, the stamps, and a
/// `channels/channel` (label, unit, type) per port channel of `channels`, in order.
pub fn audio_desc(
    broker: &str,
    host: &str,
    epoch: u64,
    g: &Geometry,
    channels: &[u32],
    clock: Clock,
) -> Vec<(String, String)> {
    let clock = match clock {
        Clock::Lsl => "in LSL's clock",
        Clock::Monotonic => {
            "in seconds of the recording host's CLOCK_MONOTONIC (liblsl's local_clock on Linux)"
        }
    };
    let mut desc: Vec<(String, String)> = vec![
        ("acquisition/manufacturer".into(), "bass".into()),
        ("bass/broker".into(), broker.into()),
        ("bass/host".into(), host.into()),
        ("bass/epoch".into(), epoch.to_string()),
        ("bass/frames_per_chunk".into(), g.frames_per_chunk.to_string()),
        ("bass/chunks_on_port".into(), g.chunks_on_port.to_string()),
        ("bass/frame_indexing".into(), "frames are numbered from 1 at the start of the acquisition (epoch); the k-th sample of a chunk pushed is frame first_frame + k; a loss marker names the frames not pushed".into()),
        ("bass/timestamps".into(), format!("each sample's capture time: the chunk's first-frame CLOCK_MONOTONIC stamp plus its offset at the nominal rate, {clock}")),
        // Frames lost to the window leave the stamps' jump: a reader must not fit one line
        // through it (pyxdf's dejittering keeps the stamps of such a stream).
        ("synchronization/can_drop_samples".into(), "true".into()),
    ];
    for &c in channels {
        desc.push((format!("channels/channel#{c}/label"), format!("ch{c}")));
        desc.push((format!("channels/channel#{c}/unit"), "int32 full scale".into()));
        desc.push((format!("channels/channel#{c}/type"), "Audio".into()));
    }
    desc
}

/// The element name of a `desc` path part (`channel#3` → `channel`).
pub fn element_name(part: &str) -> &str {
    part.split_once('#').map_or(part, |(name, _)| name)
}

/// The `desc` elements as XML (`<desc>…</desc>`), values escaped.
pub fn desc_xml(desc: &[(String, String)]) -> String {
    let mut xml = String::from("<desc>");
    // The open elements: their path parts (with the keys), outermost first.
    let mut open: Vec<&str> = Vec::new();
    for (path, value) in desc {
        let parts: Vec<&str> = path.split('/').collect();
        let (leaf, parents) = parts.split_last().expect("split yields one part at least");
        let same = open.iter().zip(parents).take_while(|(a, b)| a == b).count();
        while open.len() > same {
            xml += &format!("</{}>", element_name(open.pop().expect("an open element")));
        }
        for p in &parents[same..] {
            xml += &format!("<{}>", element_name(p));
            open.push(p);
        }
        let leaf = element_name(leaf);
        xml += &format!("<{leaf}>{}</{leaf}>", escape(value));
    }
    while let Some(p) = open.pop() {
        xml += &format!("</{}>", element_name(p));
    }
    xml + "</desc>"
}

/// `s` with XML's five special characters escaped.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out += "&amp;",
            '<' => out += "&lt;",
            '>' => out += "&gt;",
            '"' => out += "&quot;",
            '\'' => out += "&apos;",
            c => out.push(c),
        }
    }
    out
}

/// The timestamp (seconds) of frame `frame` of a chunk whose first frame `first_frame` was
/// captured at CLOCK_MONOTONIC `mono_ns`: the stamp plus the frame's offset at `rate`.
pub fn stamp_s(mono_ns: u64, first_frame: u64, frame: u64, rate: f64) -> f64 {
    mono_ns as f64 / 1e9 + (frame as f64 - first_frame as f64) / rate
}

/// Whether a frame of a chunk flagged `flags` is zero-filled by the broker: every frame of a
/// GAP chunk, and a frame of a DISCONTINUITY chunk (a gap begins or ends in it) whose samples
/// are all zero (`all_zero`).
pub fn zero_filled(flags: u32, all_zero: bool) -> bool {
    flags & chunk_flags::GAP != 0 || (flags & chunk_flags::DISCONTINUITY != 0 && all_zero)
}

/// A loss marker's text: `{"first_frame":F,"frames":N,"cause":C,"epoch":E}`.
pub fn marker_json(first_frame: u64, frames: u64, cause: &str, epoch: u64) -> String {
    format!(r#"{{"first_frame":{first_frame},"frames":{frames},"cause":"{cause}","epoch":{epoch}}}"#)
}

/// A run of zero-filled frames: its first frame, frames, and the stamp of its first frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Run {
    /// First frame.
    pub first_frame: u64,
    /// Frames.
    pub frames: u64,
    /// The stamp of its first frame.
    pub stamp: f64,
}

/// The run of zero-filled frames going on, across chunks: one gap marker per run, given when
/// it ends (at a frame not zero-filled, a loss, or the end).
#[derive(Default)]
pub struct ZeroRuns {
    run: Option<Run>,
}

impl ZeroRuns {
    /// Frame `frame` follows the last one; `zero`: it is zero-filled; `stamp` gives its stamp.
    /// Returns the run that ended before it, if any.
    pub fn frame(&mut self, frame: u64, zero: bool, stamp: impl FnOnce() -> f64) -> Option<Run> {
        match (&mut self.run, zero) {
            (Some(r), true) => {
                r.frames += 1;
                None
            }
            (None, true) => {
                self.run = Some(Run { first_frame: frame, frames: 1, stamp: stamp() });
                None
            }
            (Some(_), false) => self.run.take(),
            (None, false) => None,
        }
    }

    /// The run going on ends here (before a loss, at the end).
    pub fn end(&mut self) -> Option<Run> {
        self.run.take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn desc_xml_nests_paths_and_names_keyed_siblings_by_their_element() {
        let d = |p: &str, v: &str| (p.to_owned(), v.to_owned());
        let desc = [
            d("bass/broker", "a<b"),
            d("bass/epoch", "3"),
            d("channels/channel#0/label", "ch0"),
            d("channels/channel#0/type", "Audio"),
            d("channels/channel#1/label", "ch1"),
        ];
        assert_eq!(
            desc_xml(&desc),
            "<desc><bass><broker>a&lt;b</broker><epoch>3</epoch></bass><channels><channel><label>ch0</label><type>Audio</type></channel><channel><label>ch1</label></channel></channels></desc>"
        );
    }

    #[test]
    fn zero_runs_end_at_the_first_real_frame_and_at_the_end() {
        let mut z = ZeroRuns::default();
        assert_eq!(z.frame(10, false, || 0.0), None);
        assert_eq!(z.frame(11, true, || 1.5), None);
        assert_eq!(z.frame(12, true, || 9.0), None);
        assert_eq!(z.frame(13, false, || 0.0), Some(Run { first_frame: 11, frames: 2, stamp: 1.5 }));
        assert_eq!(z.frame(14, true, || 2.0), None);
        assert_eq!(z.end(), Some(Run { first_frame: 14, frames: 1, stamp: 2.0 }));
        assert_eq!(z.end(), None);
    }

    #[test]
    fn a_discontinuity_chunk_is_zero_filled_only_where_its_samples_are_zero() {
        assert!(zero_filled(chunk_flags::GAP, false));
        assert!(zero_filled(chunk_flags::DISCONTINUITY, true));
        assert!(!zero_filled(chunk_flags::DISCONTINUITY, false));
        assert!(!zero_filled(0, true));
    }
}
