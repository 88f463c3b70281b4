//! Device sample formats and their conversion to the port's left-justified S32.
//!
//! Every accepted format is scaled so that full scale of the device is full scale of S32:
//! S16 is shifted left by 16, the 24-bit formats by 8, FLOAT is multiplied by 2^31 and
//! saturated. Conversion is exact for the integer formats (the low bits are zero).

/// A device sample format the broker accepts (all little-endian).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleFormat {
    /// Signed 16-bit.
    S16,
    /// Signed 24-bit in the low three bytes of a 32-bit container.
    S24,
    /// Signed 24-bit packed in three bytes.
    S24_3,
    /// Signed 32-bit.
    S32,
    /// IEEE float, full scale ±1.0.
    Float,
}

impl SampleFormat {
    /// All formats, in the broker's order of preference.
    pub const PREFERENCE: [SampleFormat; 5] =
        [SampleFormat::S32, SampleFormat::S24, SampleFormat::S24_3, SampleFormat::Float, SampleFormat::S16];

    /// ALSA's name of the format.
    pub fn name(self) -> &'static str {
        match self {
            SampleFormat::S16 => "S16_LE",
            SampleFormat::S24 => "S24_LE",
            SampleFormat::S24_3 => "S24_3LE",
            SampleFormat::S32 => "S32_LE",
            SampleFormat::Float => "FLOAT_LE",
        }
    }

    /// Parses an ALSA format name (case-insensitive).
    pub fn from_name(name: &str) -> Option<SampleFormat> {
        SampleFormat::PREFERENCE.into_iter().find(|f| f.name().eq_ignore_ascii_case(name))
    }

    /// Bytes per sample.
    pub fn bytes(self) -> usize {
        match self {
            SampleFormat::S16 => 2,
            SampleFormat::S24_3 => 3,
            SampleFormat::S24 | SampleFormat::S32 | SampleFormat::Float => 4,
        }
    }

    /// The `alsa` crate's format.
    pub fn alsa(self) -> alsa::pcm::Format {
        use alsa::pcm::Format;
        match self {
            SampleFormat::S16 => Format::S16LE,
            SampleFormat::S24 => Format::S24LE,
            SampleFormat::S24_3 => Format::S243LE,
            SampleFormat::S32 => Format::S32LE,
            SampleFormat::Float => Format::FloatLE,
        }
    }
}

/// Converts little-endian samples `src` (a whole number of samples) into `dst`.
/// `dst.len()` must be `src.len() / format.bytes()`.
pub fn to_s32(format: SampleFormat, src: &[u8], dst: &mut [i32]) {
    debug_assert_eq!(src.len(), dst.len() * format.bytes());
    match format {
        SampleFormat::S16 => {
            for (d, s) in dst.iter_mut().zip(src.chunks_exact(2)) {
                *d = i32::from(i16::from_le_bytes([s[0], s[1]])) << 16;
            }
        }
        SampleFormat::S24 => {
            for (d, s) in dst.iter_mut().zip(src.chunks_exact(4)) {
                // The low 24 bits hold the sample; the top byte is ignored (sign or garbage).
                *d = (u32::from_le_bytes([s[0], s[1], s[2], s[3]]) << 8) as i32;
            }
        }
        SampleFormat::S24_3 => {
            for (d, s) in dst.iter_mut().zip(src.chunks_exact(3)) {
                *d = i32::from_le_bytes([0, s[0], s[1], s[2]]);
            }
        }
        SampleFormat::S32 => {
            for (d, s) in dst.iter_mut().zip(src.chunks_exact(4)) {
                *d = i32::from_le_bytes([s[0], s[1], s[2], s[3]]);
            }
        }
        SampleFormat::Float => {
            for (d, s) in dst.iter_mut().zip(src.chunks_exact(4)) {
                *d = float_to_s32(f32::from_le_bytes([s[0], s[1], s[2], s[3]]));
            }
        }
    }
}

/// Full scale ±1.0 to S32, saturating; NaN becomes 0.
pub fn float_to_s32(x: f32) -> i32 {
    // `as` saturates and maps NaN to 0.
    (f64::from(x) * 2_147_483_648.0).round() as i32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The names clients may force (`basskit::args`, for `bass acquire -f`) are exactly the
    /// formats converted here, in the same order of preference.
    #[test]
    fn the_shared_format_names_are_the_converted_formats() {
        assert_eq!(SampleFormat::PREFERENCE.map(SampleFormat::name), basskit::args::SAMPLE_FORMAT_NAMES);
    }

    #[test]
    fn integer_formats_are_left_justified_exactly() {
        let mut d = [0i32; 2];
        to_s32(SampleFormat::S16, &[0x34, 0x12, 0x00, 0x80], &mut d);
        assert_eq!(d, [0x1234_0000, i32::MIN]);
        to_s32(SampleFormat::S24, &[0x56, 0x34, 0x12, 0x00, 0x00, 0x00, 0x80, 0xFF], &mut d);
        assert_eq!(d, [0x1234_5600, i32::MIN]);
        to_s32(SampleFormat::S24_3, &[0x56, 0x34, 0x12, 0xFF, 0xFF, 0xFF], &mut d);
        assert_eq!(d, [0x1234_5600, -256]);
        to_s32(SampleFormat::S32, &[1, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0x7F], &mut d);
        assert_eq!(d, [1, i32::MAX]);
    }

    #[test]
    fn float_is_scaled_and_saturated() {
        assert_eq!(float_to_s32(0.5), 1 << 30);
        assert_eq!(float_to_s32(-1.0), i32::MIN);
        assert_eq!(float_to_s32(1.0), i32::MAX);
        assert_eq!(float_to_s32(7.0), i32::MAX);
        assert_eq!(float_to_s32(f32::NAN), 0);
    }

    #[test]
    fn format_names_round_trip() {
        for f in SampleFormat::PREFERENCE {
            assert_eq!(SampleFormat::from_name(&f.name().to_lowercase()), Some(f));
        }
        assert_eq!(SampleFormat::from_name("U8"), None);
    }
}
