//! The WAV files of `bass record`: a small writer (hound cannot write a plain PCM header for
//! 24/32 bits, nor say how much reached the disk, nor repair a header), a header parser for
//! `bass record --check`, and [`repair`] for a file cut short (a full disk, a killed recorder).
//!
//! ```text
//! offset  PCM (44-byte header)            EXTENSIBLE (68-byte header)
//!  0      "RIFF" u32 riff_size "WAVE"     the same
//! 12      "fmt " u32 16                   "fmt " u32 40
//! 20      u16 tag 1, channels, rate,      u16 tag 0xFFFE, channels, rate, byte rate,
//!         byte rate, block align, bits    block align, bits, u16 22, u16 valid bits,
//!                                         u32 channel mask, 16-byte PCM sub-format GUID
//! 36 | 60 "data" u32 data_size            (data_size at 40 | 64, samples from 44 | 68)
//! ```
//!
//! `riff_size` = file length − 8; `data_size` = bytes of whole frames, plus a pad byte after
//! an odd-sized data chunk (RIFF). Samples are little-endian, interleaved, integer.

use std::fs::File;
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::os::unix::fs::FileExt;
use std::path::Path;

/// WAVE_FORMAT_PCM.
pub const TAG_PCM: u16 = 1;
/// WAVE_FORMAT_EXTENSIBLE.
pub const TAG_EXTENSIBLE: u16 = 0xFFFE;
/// KSDATAFORMAT_SUBTYPE_PCM, the sub-format GUID of integer PCM.
const PCM_GUID: [u8; 16] =
    [0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x10, 0x00, 0x80, 0x00, 0x00, 0xAA, 0x00, 0x38, 0x9B, 0x71];
/// Samples buffered before a write(2).
const BUFFER: usize = 64 * 1024;

/// The header kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// WAVE_FORMAT_PCM (a 16-byte fmt chunk): every reader opens it, whatever the bits.
    Pcm,
    /// WAVE_FORMAT_EXTENSIBLE, what the format asks for above 16 bits or 2 channels.
    Extensible,
}

impl Format {
    /// The header the WAV format asks for (hound's rule): EXTENSIBLE above 16 bits or 2 channels.
    pub fn required(bits: u16, channels: u16) -> Format {
        if bits > 16 || channels > 2 {
            Format::Extensible
        } else {
            Format::Pcm
        }
    }

    /// `pcm` or `extensible` (the sidecar's `wav_format`).
    pub fn name(self) -> &'static str {
        match self {
            Format::Pcm => "pcm",
            Format::Extensible => "extensible",
        }
    }

    fn tag(self) -> u16 {
        match self {
            Format::Pcm => TAG_PCM,
            Format::Extensible => TAG_EXTENSIBLE,
        }
    }

    /// Header bytes before the samples.
    pub fn header_len(self) -> u64 {
        match self {
            Format::Pcm => 44,
            Format::Extensible => 68,
        }
    }
}

/// What a file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Spec {
    /// Channels.
    pub channels: u16,
    /// Frames per second.
    pub sample_rate: u32,
    /// Bits per sample: 16, 24 or 32.
    pub bits: u16,
    /// Header kind.
    pub format: Format,
}

impl Spec {
    /// Bytes per frame.
    pub fn frame_bytes(&self) -> u64 {
        u64::from(self.bits / 8) * u64::from(self.channels)
    }
}

/// hound's channel mask (kept so files read as they did): the first `channels` speakers.
fn channel_mask(channels: u16) -> u32 {
    (0..u32::from(channels.min(18))).fold(0, |m, c| m | 1 << c)
}

/// The header of a file of `spec` with `data_bytes` bytes of samples.
pub fn header(spec: &Spec, data_bytes: u64) -> Vec<u8> {
    let mut h = Vec::with_capacity(68);
    let pad = data_bytes & 1;
    let riff = (spec.format.header_len() - 8 + data_bytes + pad).min(u64::from(u32::MAX)) as u32;
    let block = spec.frame_bytes() as u16;
    h.extend_from_slice(b"RIFF");
    h.extend_from_slice(&riff.to_le_bytes());
    h.extend_from_slice(b"WAVEfmt ");
    let fmt_len: u32 = if spec.format == Format::Pcm { 16 } else { 40 };
    h.extend_from_slice(&fmt_len.to_le_bytes());
    h.extend_from_slice(&spec.format.tag().to_le_bytes());
    h.extend_from_slice(&spec.channels.to_le_bytes());
    h.extend_from_slice(&spec.sample_rate.to_le_bytes());
    h.extend_from_slice(&(spec.sample_rate.wrapping_mul(u32::from(block))).to_le_bytes());
    h.extend_from_slice(&block.to_le_bytes());
    h.extend_from_slice(&spec.bits.to_le_bytes());
    if spec.format == Format::Extensible {
        h.extend_from_slice(&22u16.to_le_bytes());
        h.extend_from_slice(&spec.bits.to_le_bytes()); // valid bits
        h.extend_from_slice(&channel_mask(spec.channels).to_le_bytes());
        h.extend_from_slice(&PCM_GUID);
    }
    h.extend_from_slice(b"data");
    h.extend_from_slice(&(data_bytes.min(u64::from(u32::MAX)) as u32).to_le_bytes());
    debug_assert_eq!(h.len() as u64, spec.format.header_len());
    h
}

/// Writes the sizes of a header of `format` for `data_bytes` bytes of samples in place
/// (positioned writes: the file offset does not move).
pub fn patch_sizes(file: &File, format: Format, data_bytes: u64) -> io::Result<()> {
    let pad = data_bytes & 1;
    let riff = (format.header_len() - 8 + data_bytes + pad).min(u64::from(u32::MAX)) as u32;
    file.write_all_at(&riff.to_le_bytes(), 4)?;
    let data = data_bytes.min(u64::from(u32::MAX)) as u32;
    file.write_all_at(&data.to_le_bytes(), format.header_len() - 4)
}

/// A WAV file being written: samples are buffered, and every byte that reaches the file is
/// counted, so a failed write (a full disk) leaves a known number of bytes behind.
///
/// ```
/// use bass_cli::wav::{Format, Spec, Writer};
/// let path = std::env::temp_dir().join(format!("bass-doc-wav-{}.wav", std::process::id()));
/// let spec = Spec { channels: 2, sample_rate: 48000, bits: 24, format: Format::Pcm };
/// let mut w = Writer::new(std::fs::File::create(&path)?, spec)?;
/// for s in [1, -1, 2, -2] {
///     w.sample(s)?;
/// }
/// assert_eq!(w.finalize()?, 2); // frames
/// assert_eq!(hound::WavReader::open(&path).unwrap().duration(), 2);
/// std::fs::remove_file(&path)?;
/// # Ok::<(), std::io::Error>(())
/// ```
pub struct Writer {
    file: File,
    spec: Spec,
    buf: Vec<u8>,
    /// Sample bytes in the file.
    on_disk: u64,
}

impl Writer {
    /// Writes the header of an empty file (sizes 0) to `file`, a new empty file.
    pub fn new(mut file: File, spec: Spec) -> io::Result<Writer> {
        file.write_all(&header(&spec, 0))?;
        Ok(Writer { file, spec, buf: Vec::with_capacity(BUFFER), on_disk: 0 })
    }

    /// The file's spec.
    pub fn spec(&self) -> &Spec {
        &self.spec
    }

    /// The open file.
    pub fn file(&self) -> &File {
        &self.file
    }

    /// Queues one sample (the low `bits` of `s`); writes the buffer when it is full.
    pub fn sample(&mut self, s: i32) -> io::Result<()> {
        let b = s.to_le_bytes();
        self.buf.extend_from_slice(&b[..usize::from(self.spec.bits / 8)]);
        if self.buf.len() >= BUFFER {
            self.flush()?;
        }
        Ok(())
    }

    /// Whole frames written or queued.
    pub fn frames(&self) -> u64 {
        (self.on_disk + self.buf.len() as u64) / self.spec.frame_bytes()
    }

    /// Sample bytes in the file (what reached it, possibly part of a frame after a failure).
    pub fn bytes_on_disk(&self) -> u64 {
        self.on_disk
    }

    /// Writes the queued samples; on an error, what reached the file is still counted.
    pub fn flush(&mut self) -> io::Result<()> {
        let mut done = 0;
        let r = loop {
            if done == self.buf.len() {
                break Ok(());
            }
            match self.file.write(&self.buf[done..]) {
                Ok(0) => break Err(io::Error::from(io::ErrorKind::WriteZero)),
                Ok(n) => {
                    done += n;
                    self.on_disk += n as u64;
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => break Err(e),
            }
        };
        self.buf.drain(..done);
        r
    }

    /// Writes the queued samples and brings the header sizes up to date: the file is a valid
    /// WAV of [`Writer::frames`] frames as it stands. Returns the frames.
    pub fn checkpoint(&mut self) -> io::Result<u64> {
        self.flush()?;
        patch_sizes(&self.file, self.spec.format, self.on_disk)?;
        Ok(self.on_disk / self.spec.frame_bytes())
    }

    /// Like [`Writer::checkpoint`], and adds the pad byte an odd-sized data chunk needs.
    pub fn finalize(&mut self) -> io::Result<u64> {
        self.flush()?;
        if self.on_disk & 1 == 1 {
            self.file.write_all(&[0])?;
        }
        patch_sizes(&self.file, self.spec.format, self.on_disk)?;
        Ok(self.on_disk / self.spec.frame_bytes())
    }
}

/// The header of a WAV file as read back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Info {
    /// The fmt chunk's format tag.
    pub tag: u16,
    /// Channels.
    pub channels: u16,
    /// Frames per second.
    pub sample_rate: u32,
    /// Bits per sample.
    pub bits: u16,
    /// Bytes per frame (block align).
    pub block_align: u16,
    /// The RIFF size field.
    pub riff_size: u32,
    /// Offset of the first sample.
    pub data_offset: u64,
    /// The data chunk's size field.
    pub data_size: u32,
    /// Length of the file.
    pub file_len: u64,
}

impl Info {
    /// The header kind, if the tag is one of ours.
    pub fn format(&self) -> Option<Format> {
        match self.tag {
            TAG_PCM => Some(Format::Pcm),
            TAG_EXTENSIBLE => Some(Format::Extensible),
            _ => None,
        }
    }
}

fn read_u32(r: &mut impl Read) -> io::Result<u32> {
    let mut b = [0; 4];
    r.read_exact(&mut b)?;
    Ok(u32::from_le_bytes(b))
}

/// Reads the RIFF/WAVE header of `r` up to the start of the data chunk (chunks before it are
/// skipped; the fmt chunk must come first, as everything writes it).
pub fn parse(r: &mut (impl Read + Seek)) -> Result<Info, String> {
    let bad = |e: io::Error| format!("not a complete WAV header: {e}");
    let file_len = r.seek(SeekFrom::End(0)).map_err(bad)?;
    r.seek(SeekFrom::Start(0)).map_err(bad)?;
    let mut id = [0u8; 4];
    r.read_exact(&mut id).map_err(bad)?;
    let riff_size = read_u32(r).map_err(bad)?;
    let mut wave = [0u8; 4];
    r.read_exact(&mut wave).map_err(bad)?;
    if &id != b"RIFF" || &wave != b"WAVE" {
        return Err("not a RIFF/WAVE file".into());
    }
    let mut fmt: Option<[u8; 16]> = None;
    let mut tag = 0;
    let mut pos = 12u64;
    loop {
        r.read_exact(&mut id).map_err(|e| format!("no data chunk: {e}"))?;
        let len = read_u32(r).map_err(bad)?;
        pos += 8;
        if &id == b"fmt " {
            if len < 16 {
                return Err(format!("fmt chunk of {len} bytes"));
            }
            let mut f = [0u8; 16];
            r.read_exact(&mut f).map_err(bad)?;
            tag = u16::from_le_bytes([f[0], f[1]]);
            fmt = Some(f);
        } else if &id == b"data" {
            let f = fmt.ok_or("data chunk before the fmt chunk")?;
            let u16_at = |i: usize| u16::from_le_bytes([f[i], f[i + 1]]);
            return Ok(Info {
                tag,
                channels: u16_at(2),
                sample_rate: u32::from_le_bytes([f[4], f[5], f[6], f[7]]),
                block_align: u16_at(12),
                bits: u16_at(14),
                riff_size,
                data_offset: pos,
                data_size: len,
                file_len,
            });
        }
        pos += u64::from(len) + u64::from(len & 1);
        r.seek(SeekFrom::Start(pos)).map_err(bad)?;
    }
}

/// Opens `path` for writing without following a symbolic link.
fn open_rw_nofollow(path: &Path) -> io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new().read(true).write(true).custom_flags(libc::O_NOFOLLOW).open(path)
}

/// Cuts the WAV file `path` to at most `max_frames` whole frames of `frame_bytes` (`None`: as
/// many whole frames as the file holds after its data chunk starts) and writes header sizes
/// that match. Returns the frames kept.
pub fn repair(path: &Path, frame_bytes: u64, max_frames: Option<u64>) -> io::Result<u64> {
    let mut f = open_rw_nofollow(path)?;
    let info = parse(&mut f).map_err(io::Error::other)?;
    let format = info.format().ok_or_else(|| io::Error::other(format!("format tag {:#x}", info.tag)))?;
    if info.data_offset != format.header_len() {
        return Err(io::Error::other("not a header bass record writes (chunks before the data)"));
    }
    let mut frames = info.file_len.saturating_sub(info.data_offset) / frame_bytes;
    if let Some(m) = max_frames {
        frames = frames.min(m);
    }
    let data = frames * frame_bytes;
    f.set_len(info.data_offset + data)?;
    if data & 1 == 1 && f.set_len(info.data_offset + data + 1).is_err() {
        // No room for the pad byte: most readers do without it; keep the file as it is.
    }
    patch_sizes(&f, format, data)?;
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("bass-wav-{}-{name}", std::process::id()));
        let _ = std::fs::remove_file(&d);
        d
    }

    fn write(path: &Path, spec: Spec, frames: u64) {
        let mut w = Writer::new(File::create(path).unwrap(), spec).unwrap();
        for f in 0..frames {
            for c in 0..spec.channels {
                w.sample((f as i32) * 16 + i32::from(c) - 100).unwrap();
            }
        }
        assert_eq!(w.finalize().unwrap(), frames);
    }

    fn hound_samples(path: &Path) -> (hound::WavSpec, Vec<i32>) {
        let mut r = hound::WavReader::open(path).unwrap();
        (r.spec(), r.samples::<i32>().map(|s| s.unwrap()).collect())
    }

    #[test]
    fn both_headers_at_every_width_read_back_in_hound() {
        for format in [Format::Pcm, Format::Extensible] {
            for bits in [16u16, 24, 32] {
                for channels in [1u16, 2, 3] {
                    let p = temp(&format!("{}-{bits}-{channels}", format.name()));
                    let spec = Spec { channels, sample_rate: 8000, bits, format };
                    write(&p, spec, 101);
                    let (s, samples) = hound_samples(&p);
                    assert_eq!((s.channels, s.sample_rate, s.bits_per_sample), (channels, 8000, bits));
                    let want: Vec<i32> = (0..101)
                        .flat_map(|f| (0..channels).map(move |c| f * 16 + i32::from(c) - 100))
                        .collect();
                    assert_eq!(samples, want, "{format:?} {bits} bits {channels} channels");
                    let info = parse(&mut File::open(&p).unwrap()).unwrap();
                    assert_eq!(info.format(), Some(format));
                    assert_eq!(u64::from(info.data_size), 101 * spec.frame_bytes());
                    assert_eq!(u64::from(info.riff_size) + 8, info.file_len, "pad byte included");
                    std::fs::remove_file(&p).unwrap();
                }
            }
        }
    }

    #[test]
    fn repair_keeps_whole_frames_and_patches_the_sizes() {
        let p = temp("repair");
        let spec = Spec { channels: 2, sample_rate: 8000, bits: 24, format: Format::Extensible };
        write(&p, spec, 50);
        // A cut mid-frame, with stale sizes (as a full disk or a killed recorder leaves it).
        let f = std::fs::OpenOptions::new().write(true).open(&p).unwrap();
        f.set_len(68 + 20 * 6 + 4).unwrap();
        drop(f);
        let stale = hound::WavReader::open(&p).unwrap().samples::<i32>().collect::<Result<Vec<_>, _>>();
        assert!(stale.is_err(), "the stale header claims frames that are gone");
        assert_eq!(repair(&p, 6, None).unwrap(), 20);
        assert_eq!(std::fs::metadata(&p).unwrap().len(), 68 + 120);
        assert_eq!(hound_samples(&p).1.len(), 40);
        assert_eq!(repair(&p, 6, Some(7)).unwrap(), 7, "cut to a number of frames");
        assert_eq!(hound_samples(&p).1.len(), 14);
        std::fs::remove_file(&p).unwrap();
    }

    #[test]
    fn a_checkpoint_leaves_a_valid_file_as_it_stands() {
        let p = temp("checkpoint");
        let spec = Spec { channels: 1, sample_rate: 8000, bits: 32, format: Format::Pcm };
        let mut w = Writer::new(File::create(&p).unwrap(), spec).unwrap();
        for s in 0..30 {
            w.sample(s).unwrap();
        }
        assert_eq!(w.checkpoint().unwrap(), 30);
        assert_eq!(hound_samples(&p).1, (0..30).collect::<Vec<_>>());
        w.sample(99).unwrap();
        w.flush().unwrap(); // written but not in the header: readers stop at the checkpoint
        assert_eq!(hound_samples(&p).1.len(), 30);
        std::fs::remove_file(&p).unwrap();
    }

    #[test]
    fn a_foreign_file_is_not_a_wav() {
        let mut c = io::Cursor::new(b"RIFX\0\0\0\0WAVE".to_vec());
        assert!(parse(&mut c).unwrap_err().contains("RIFF"));
        let mut c = io::Cursor::new(b"RIFF\0\0\0\0WAVEfmt ".to_vec());
        assert!(parse(&mut c).is_err());
    }
}
