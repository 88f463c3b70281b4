//! `bass record --check FILE.xdf`: whether an XDF recording of `bass record` is well formed —
//! the framing of every chunk, one FileHeader first, the two stream headers (an `Audio` int32
//! stream naming its first frame and epoch, a `Markers` string stream), every Samples chunk
//! read to its end, the markers' JSON, the stamps against the frame indices the markers give,
//! the gap markers' frames zeros, and the footers against what the file holds. A file without
//! footers (a recorder killed: its last checkpoint) passes, and the line says so.

use std::path::Path;

use super::xdf_out::{tag, BOUNDARY, MAGIC};
use crate::labstream::{GAP, OVERRUN};

/// Most channels a bass stream has.
const MAX_CHANNELS: u64 = 64;

/// A stream's header facts and what its chunks held.
#[derive(Default)]
struct Stream {
    name: String,
    kind: String,
    format: String,
    channels: usize,
    rate: f64,
    epoch: Option<u64>,
    first_frame: Option<u64>,
    samples: u64,
    first_stamp: Option<f64>,
    last_stamp: f64,
    offsets: u64,
    footer: Option<String>,
    /// Audio: the frame index and stamp of each Samples chunk's first sample, its samples.
    chunks: Vec<(u64, f64, u64)>,
    /// Audio: runs of all-zero frames (first frame, frames).
    zeros: Vec<(u64, u64)>,
    /// Markers: (first_frame, frames, cause, stamp).
    markers: Vec<(u64, u64, String, f64)>,
}

/// What the file held so far.
#[derive(Default)]
struct File {
    /// The audio stream and its id.
    audio: Option<(u32, Stream)>,
    /// The marker stream and its id.
    markers: Option<(u32, Stream)>,
    /// Frames lost (the overrun markers so far).
    lost: u64,
    boundaries: u64,
}

/// A cursor over a chunk's content; every read is bounds-checked.
struct Cur<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Cur<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len());
        let end = end.ok_or_else(|| format!("{n} bytes wanted at offset {} of {}", self.at, self.b.len()))?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }

    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }

    fn f64(&mut self) -> Result<f64, String> {
        let v = f64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes"));
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("a non-finite number {v}"))
        }
    }

    /// An XDF variable-length integer (1, 4 or 8 bytes after its size byte).
    fn varlen(&mut self) -> Result<u64, String> {
        match self.u8()? {
            1 => Ok(u64::from(self.u8()?)),
            4 => Ok(u64::from(self.u32()?)),
            8 => Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes"))),
            n => Err(format!("a variable-length integer of {n} bytes (1, 4 or 8)")),
        }
    }

    fn rest(&mut self) -> &'a [u8] {
        let s = &self.b[self.at..];
        self.at = self.b.len();
        s
    }
}

/// The text of the first element `path` (`a/b`: element `b` inside the first `a`) of `xml`,
/// entities decoded; None if absent.
fn xml_text(xml: &str, path: &str) -> Option<String> {
    let mut scope = xml;
    for part in path.split('/') {
        let open = format!("<{part}>");
        let close = format!("</{part}>");
        let s = scope.find(&open)? + open.len();
        let e = s + scope[s..].find(&close)?;
        scope = &scope[s..e];
    }
    Some(
        scope
            .replace("&lt;", "<")
            .replace("&gt;", ">")
            .replace("&quot;", "\"")
            .replace("&apos;", "'")
            .replace("&amp;", "&"),
    )
}

fn xml_num<T: std::str::FromStr>(xml: &str, path: &str) -> Result<T, String> {
    let t = xml_text(xml, path).ok_or_else(|| format!("no <{path}>"))?;
    t.trim().parse().map_err(|_| format!("<{path}> {t:?} is not a number"))
}

/// Checks the XDF file `path`: Ok(the "ok" line) or the problems.
pub fn check_xdf(path: &Path) -> Result<String, Vec<String>> {
    let data = std::fs::read(path).map_err(|e| vec![format!("cannot read {}: {e}", path.display())])?;
    if !data.starts_with(MAGIC) {
        return Err(vec![format!("{}: no XDF magic \"XDF:\" at its start", path.display())]);
    }
    let mut problems = Vec::new();
    let mut file = File::default();
    let (mut headers, mut at, mut n) = (0, MAGIC.len(), 0u64);
    while at < data.len() {
        let mut c = Cur { b: &data, at };
        let framed = c.varlen().and_then(|len| {
            if len < 2 {
                return Err(format!("a length of {len} (the tag alone is 2)"));
            }
            let content = c.take(usize::try_from(len).unwrap_or(usize::MAX))?;
            Ok((u16::from_le_bytes([content[0], content[1]]), &content[2..]))
        });
        let (t, content) = match framed {
            Ok(f) => f,
            Err(e) => {
                problems.push(format!("chunk {n} at byte {at}: {e}: the file ends in a torn chunk"));
                break;
            }
        };
        if n == 0 && t != tag::FILE_HEADER {
            problems.push(format!("the first chunk has tag {t}, not the FileHeader (1)"));
        }
        let r = match t {
            tag::FILE_HEADER => {
                headers += 1;
                file_header(content, n)
            }
            tag::BOUNDARY if content == BOUNDARY => {
                file.boundaries += 1;
                Ok(())
            }
            tag::BOUNDARY => Err("a Boundary chunk without the spec's 16-byte UUID".into()),
            tag::STREAM_HEADER | tag::SAMPLES | tag::CLOCK_OFFSET | tag::STREAM_FOOTER => {
                file.stream_chunk(t, content)
            }
            t => Err(format!("an unknown tag {t}")),
        };
        if let Err(e) = r {
            problems.push(format!("chunk {n} (tag {t}) at byte {at}: {e}"));
        }
        at = c.at;
        n += 1;
    }
    if headers != 1 {
        problems.push(format!("{headers} FileHeader chunks, not 1"));
    }
    let line = file.finish(path, &mut problems);
    if problems.is_empty() {
        Ok(line)
    } else {
        Err(problems)
    }
}

fn file_header(content: &[u8], n: u64) -> Result<(), String> {
    let xml = std::str::from_utf8(content).map_err(|_| "a FileHeader that is not UTF-8")?;
    match xml_text(xml, "info/version") {
        Some(v) if v == "1.0" && n == 0 => Ok(()),
        Some(v) if v == "1.0" => Err("a second FileHeader".into()),
        v => Err(format!("a FileHeader of version {v:?}, not 1.0")),
    }
}

impl File {
    /// A chunk of one stream (StreamHeader, Samples, ClockOffset, StreamFooter).
    fn stream_chunk(&mut self, t: u16, content: &[u8]) -> Result<(), String> {
        let mut c = Cur { b: content, at: 0 };
        let id = c.u32()?;
        if t == tag::STREAM_HEADER {
            if [&self.audio, &self.markers].iter().any(|s| s.as_ref().is_some_and(|s| s.0 == id)) {
                return Err(format!("a second StreamHeader of stream {id}"));
            }
            let s = stream_header(c.rest())?;
            let slot = if s.kind == "Audio" { &mut self.audio } else { &mut self.markers };
            if slot.is_some() {
                return Err(format!("a second {} stream ({id})", s.kind));
            }
            *slot = Some((id, s));
            return Ok(());
        }
        // The audio's next frame, for an overrun marker.
        let next = self.audio.as_ref().map(|(_, a)| a.first_frame.unwrap_or(0) + a.samples + self.lost);
        let lost = &mut self.lost;
        let s = match (&mut self.audio, &mut self.markers) {
            (Some((i, a)), _) if *i == id => a,
            (_, Some((i, m))) if *i == id => m,
            _ => return Err(format!("stream {id} before its StreamHeader")),
        };
        if s.footer.is_some() {
            return Err(format!("stream {id} goes on after its StreamFooter"));
        }
        match t {
            tag::SAMPLES => samples(&mut c, s, lost, next)?,
            tag::CLOCK_OFFSET => {
                let (_time, value) = (c.f64()?, c.f64()?);
                if value != 0.0 {
                    return Err(format!(
                        "a clock offset of {value} s (bass writes 0: its stamps are this host's)"
                    ));
                }
                s.offsets += 1;
            }
            _ => {
                let xml = std::str::from_utf8(c.rest()).map_err(|_| "a StreamFooter that is not UTF-8")?;
                s.footer = Some(xml.to_owned());
            }
        }
        if c.at != content.len() {
            return Err(format!("{} bytes after the content", content.len() - c.at));
        }
        Ok(())
    }

    /// The checks of the whole file; the "ok" line.
    fn finish(&self, path: &Path, problems: &mut Vec<String>) -> String {
        let (Some((_, a)), Some((_, m))) = (&self.audio, &self.markers) else {
            problems.push("not an Audio and a Markers stream".into());
            return String::new();
        };
        stamps(a, m, problems);
        for (s, what) in [(a, "audio"), (m, "markers")] {
            footer(s, what, self.lost, problems);
        }
        let (first, epoch) = (a.first_frame.unwrap_or(0), a.epoch.unwrap_or(0));
        let frames = a.samples + self.lost;
        let gaps = m.markers.iter().filter(|k| k.2 == GAP).count();
        let closed = match (&a.footer, &m.footer) {
            (Some(_), Some(_)) => "with footers",
            _ => "in progress: no footers (the recorder did not close it; its last checkpoint)",
        };
        format!(
            "ok: {}: {frames} frames ({:.3} s), frames {first}..={} of epoch {epoch}, {} channels at {} Hz int32, {} lost; stream {:?}: {} markers ({} overrun, {gaps} gap); {} ClockOffsets, {} Boundaries; {closed}",
            path.display(),
            frames as f64 / a.rate,
            (first + frames).max(1) - 1,
            a.channels,
            a.rate,
            self.lost,
            m.name,
            m.samples,
            m.markers.len() - gaps,
            a.offsets,
            self.boundaries,
        )
    }
}

fn stream_header(xml: &[u8]) -> Result<Stream, String> {
    let xml = std::str::from_utf8(xml).map_err(|_| "a StreamHeader that is not UTF-8")?;
    let channels: u64 = xml_num(xml, "info/channel_count")?;
    if !(1..=MAX_CHANNELS).contains(&channels) {
        return Err(format!("channel_count {channels} (1..={MAX_CHANNELS})"));
    }
    let rate: f64 = xml_num(xml, "info/nominal_srate")?;
    if !rate.is_finite() || rate < 0.0 {
        return Err(format!("nominal_srate {rate}"));
    }
    let s = Stream {
        name: xml_text(xml, "info/name").unwrap_or_default(),
        kind: xml_text(xml, "info/type").unwrap_or_default(),
        format: xml_text(xml, "info/channel_format").unwrap_or_default(),
        channels: channels as usize,
        rate,
        epoch: xml_num(xml, "info/desc/bass/epoch").ok(),
        first_frame: xml_num(xml, "info/desc/bass/first_frame").ok().filter(|&f: &u64| f >= 1),
        ..Stream::default()
    };
    match (s.kind.as_str(), s.format.as_str()) {
        ("Audio", "int32") if rate > 0.0 && s.epoch.is_some() && s.first_frame.is_some() => Ok(s),
        ("Audio", _) => Err(format!(
            "an Audio stream of format {:?} at {rate} Hz, epoch {:?}, first frame {:?} (bass writes int32 at the port's rate, naming both)",
            s.format, s.epoch, s.first_frame
        )),
        ("Markers", "string") if channels == 1 && rate == 0.0 => Ok(s),
        (k, f) => Err(format!("a stream of type {k:?} and format {f:?} (bass writes Audio int32 and Markers string)")),
    }
}

/// A Samples chunk of stream `s`, read to its end; `lost` the frames lost so far (an overrun
/// marker adds to it), `next` the audio's next frame.
fn samples(c: &mut Cur, s: &mut Stream, lost: &mut u64, next: Option<u64>) -> Result<(), String> {
    let count = c.varlen()?;
    let tdiff = if s.rate > 0.0 { 1.0 / s.rate } else { 0.0 };
    for k in 0..count {
        let stamp = match c.u8()? {
            0 if s.samples > 0 => s.last_stamp + tdiff,
            0 => return Err("the stream's first sample has no stamp".into()),
            8 => c.f64()?,
            b => return Err(format!("a TimeStampBytes of {b} (0 or 8)")),
        };
        if s.samples > 0 && stamp < s.last_stamp - tdiff {
            return Err(format!(
                "sample {} stamped {stamp:.6}, before the one before it ({:.6})",
                s.samples, s.last_stamp
            ));
        }
        if s.format == "int32" {
            let zero = c.take(4 * s.channels)?.iter().all(|&b| b == 0);
            let frame = s.first_frame.unwrap_or(0) + s.samples + *lost;
            if k == 0 {
                s.chunks.push((frame, stamp, count));
            }
            match s.zeros.last_mut() {
                Some((f, m)) if zero && *f + *m == frame => *m += 1,
                _ if zero => s.zeros.push((frame, 1)),
                _ => {}
            }
        } else {
            let len = c.varlen()?;
            let v = c.take(usize::try_from(len).unwrap_or(usize::MAX))?;
            let text = std::str::from_utf8(v).map_err(|_| "a marker that is not UTF-8")?;
            let (f, n, cause) = marker(text)?;
            if cause == OVERRUN {
                if next != Some(f) {
                    return Err(format!(
                        "an overrun marker of frame {f} where the audio is at frame {next:?}"
                    ));
                }
                *lost += n;
            }
            s.markers.push((f, n, cause, stamp));
        }
        s.first_stamp.get_or_insert(stamp);
        s.last_stamp = stamp;
        s.samples += 1;
    }
    Ok(())
}

/// A marker's JSON `{"first_frame","frames","cause","epoch"}`: its frames and cause.
fn marker(text: &str) -> Result<(u64, u64, String), String> {
    let v: serde_json::Value = serde_json::from_str(text).map_err(|e| format!("a marker {text:?}: {e}"))?;
    let num = |k: &str| v.get(k).and_then(serde_json::Value::as_u64);
    match (num("first_frame"), num("frames"), v.get("cause").and_then(|c| c.as_str()), num("epoch")) {
        (Some(f), Some(n), Some(c), Some(_)) if f >= 1 && n >= 1 && (c == OVERRUN || c == GAP) => {
            Ok((f, n, c.to_owned()))
        }
        _ => Err(format!("a marker {text:?} (first_frame >= 1, frames >= 1, cause overrun or gap, epoch)")),
    }
}

/// Every chunk's stamp against its frame index (within half a chunk of the chunk before it:
/// a jump the markers do not explain is a problem), every marker's stamp (its frame's, within
/// 1 µs: an overrun's from the chunk after it) and every gap marker's frames (all zeros).
fn stamps(a: &Stream, m: &Stream, problems: &mut Vec<String>) {
    let chunk_s = a.chunks.iter().map(|c| c.2).max().unwrap_or(1) as f64 / a.rate;
    for w in a.chunks.windows(2) {
        let expected = w[0].1 + (w[1].0 - w[0].0) as f64 / a.rate;
        if (w[1].1 - expected).abs() > chunk_s / 2.0 {
            problems.push(format!(
                "the chunk at frame {} is stamped {:.6}, {:+.6} s from its frame index (a loss without its marker, or a marker of other frames)",
                w[1].0,
                w[1].1,
                w[1].1 - expected
            ));
        }
    }
    for (f, n, cause, t) in &m.markers {
        let i = if cause == OVERRUN {
            a.chunks.partition_point(|c| c.0 < *f).min(a.chunks.len().saturating_sub(1))
        } else {
            a.chunks.partition_point(|c| c.0 <= *f).saturating_sub(1)
        };
        if let Some(&(cf, ct, _)) = a.chunks.get(i) {
            let expected = ct + (*f as f64 - cf as f64) / a.rate;
            if (t - expected).abs() > 1e-6 {
                problems.push(format!(
                    "the {cause} marker of frame {f} is stamped {t:.7}, not its frame's {expected:.7}"
                ));
            }
        }
        if cause == GAP {
            let z = a.zeros.partition_point(|z| z.0 <= *f).saturating_sub(1);
            if !a.zeros.get(z).is_some_and(|&(zf, zn)| zf <= *f && f + n <= zf + zn) {
                problems.push(format!(
                    "the gap marker of frames {f}..{} names frames that are not all zeros",
                    f + n
                ));
            }
        }
    }
}

/// Stream `s`'s footer (if any) against what its chunks held; `lost` the frames lost.
fn footer(s: &Stream, what: &str, lost: u64, problems: &mut Vec<String>) {
    let Some(xml) = &s.footer else { return };
    let mut bad = |e: String| problems.push(format!("the {what} footer: {e}"));
    match xml_num::<u64>(xml, "info/sample_count") {
        Ok(n) if n == s.samples => {}
        Ok(n) => bad(format!("sample_count {n}, the chunks hold {}", s.samples)),
        Err(e) => bad(e),
    }
    for (name, v) in
        [("info/first_timestamp", s.first_stamp.unwrap_or(0.0)), ("info/last_timestamp", s.last_stamp)]
    {
        match xml_num::<f64>(xml, name) {
            Ok(t) if (t - v).abs() <= 1e-6 => {}
            Ok(t) => bad(format!("<{name}> {t}, the chunks say {v}")),
            Err(e) => bad(e),
        }
    }
    let offsets = xml.matches("<offset>").count() as u64;
    if offsets != s.offsets {
        bad(format!("{offsets} clock offsets, the file has {} ClockOffset chunks", s.offsets));
    }
    if what == "audio" {
        match (xml_num::<u64>(xml, "info/bass/frames"), xml_num::<u64>(xml, "info/bass/lost_frames")) {
            (Ok(f), Ok(l)) if f == s.samples + lost && l == lost => {}
            (Ok(f), Ok(l)) => bad(format!(
                "{f} frames, {l} lost; the chunks hold {} samples and the markers {lost} lost frames",
                s.samples
            )),
            (Err(e), _) | (_, Err(e)) => bad(e),
        }
    }
}
