//! Foxglove's `foxglove_msgs/msg/RawAudio` in ROS 2 form: the message Foxglove's Audio panel
//! plays, written beside `AudioDataStamped` by `bass record --format mcap --foxglove-audio`.
//!
//! [`RAW_AUDIO_DEFINITION`] holds the fields of Foxglove's published ros2msg definition
//! (`schemas/ros2/RawAudio.msg` of github.com/foxglove/foxglove-sdk, in the order and with the
//! types given there; comments left out, as for the other definitions of [`super`]) and the
//! `builtin_interfaces/Time` it depends on, in rosbag2's form. The CDR body, after the
//! encapsulation header `00 01 00 00` (alignment counted from the body's start):
//!
//! ```text
//!  0        4          8          12              12+n  pad4   +4               +4      +4
//!  +--------+----------+----------+---------------+-----+-----+-----------------+-------+-------+
//!  | sec i32| nsec u32 | cnt u32  | data: cnt B   | ... | len | format, NUL     | rate  | chans |
//!  +--------+----------+----------+---------------+-----+-----+-----------------+-------+-------+
//!   timestamp           data (uint8[])                    format (string)       u32     u32
//! ```
//!
//! bass writes `format` [`PCM_S16`] (the only format the panel plays): signed 16-bit samples,
//! interleaved, little-endian.
//!
//! ```
//! use basskit::ros2::foxglove::RawAudio;
//! use basskit::ros2::Time;
//! let mut bytes = Vec::new();
//! RawAudio::encode_pcm_s16(Time::from_ns(1_250_000_000), [1i16, -2, 3, -4].into_iter(), 8000, 2, &mut bytes);
//! let msg = RawAudio::decode(&bytes).unwrap();
//! assert_eq!(msg.pcm_s16().unwrap(), vec![1, -2, 3, -4]);
//! assert_eq!((msg.format.as_str(), msg.sample_rate, msg.number_of_channels), ("pcm-s16", 8000, 2));
//! ```

use super::{name_token, CdrError, In, Out, Time};

/// Type name of Foxglove's raw audio message in ROS 2 form (the name Foxglove recognises).
pub const RAW_AUDIO: &str = "foxglove_msgs/msg/RawAudio";

/// `RawAudio.format` of signed 16-bit little-endian PCM, the format Foxglove's Audio panel plays.
pub const PCM_S16: &str = "pcm-s16";

/// Complete `ros2msg` definition of [`RAW_AUDIO`].
pub const RAW_AUDIO_DEFINITION: &str = "builtin_interfaces/Time timestamp
uint8[] data
string format
uint32 sample_rate
uint32 number_of_channels

================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
";

/// The RawAudio topic of `broker`: `/bass/<broker>/raw_audio` (see [`name_token`]).
pub fn topic(broker: &str) -> String {
    format!("/bass/{}/raw_audio", name_token(broker))
}

/// `foxglove_msgs/msg/RawAudio`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RawAudio {
    /// Time of the block's first frame.
    pub timestamp: Time,
    /// The samples, interleaved, little-endian, as `format` says.
    pub data: Vec<u8>,
    /// [`PCM_S16`] for bass.
    pub format: String,
    /// Frames per second.
    pub sample_rate: u32,
    /// Channels per frame.
    pub number_of_channels: u32,
}

impl RawAudio {
    /// Serialises a [`PCM_S16`] block of `samples` (interleaved frames of `channels`) without an
    /// intermediate byte buffer. `out` is cleared first.
    pub fn encode_pcm_s16(
        timestamp: Time,
        samples: impl ExactSizeIterator<Item = i16>,
        sample_rate: u32,
        channels: u32,
        out: &mut Vec<u8>,
    ) {
        let mut o = Out::new(out);
        o.i32(timestamp.sec);
        o.u32(timestamp.nanosec);
        o.u32((samples.len() * 2) as u32);
        o.buf.reserve(samples.len() * 2);
        for s in samples {
            o.buf.extend_from_slice(&s.to_le_bytes());
        }
        o.string(PCM_S16);
        o.u32(sample_rate);
        o.u32(channels);
    }

    /// Serialises the message into `out` (cleared first).
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut o = Out::new(out);
        o.i32(self.timestamp.sec);
        o.u32(self.timestamp.nanosec);
        o.u32(self.data.len() as u32);
        o.buf.extend_from_slice(&self.data);
        o.string(&self.format);
        o.u32(self.sample_rate);
        o.u32(self.number_of_channels);
    }

    /// Reads a CDR payload, every length checked.
    pub fn decode(payload: &[u8]) -> Result<Self, CdrError> {
        let mut i = In::new(payload)?;
        let sec = i.u32("timestamp.sec")? as i32;
        let nanosec = i.u32("timestamp.nanosec")?;
        if nanosec >= 1_000_000_000 {
            return Err(CdrError::Range { field: "timestamp.nanosec", value: nanosec.into() });
        }
        let m = RawAudio {
            timestamp: Time { sec, nanosec },
            data: i.bytes("data")?.to_vec(),
            format: i.string("format")?,
            sample_rate: i.u32("sample_rate")?,
            number_of_channels: i.u32("number_of_channels")?,
        };
        i.end()?;
        Ok(m)
    }

    /// The data as [`PCM_S16`] samples; an error if `format` is another or the data's length is
    /// not a whole number of frames of `number_of_channels` (which must not be 0).
    pub fn pcm_s16(&self) -> Result<Vec<i16>, CdrError> {
        if self.format != PCM_S16 {
            return Err(CdrError::Unexpected {
                field: "format",
                found: self.format.clone(),
                expected: PCM_S16,
            });
        }
        let frame = 2 * self.number_of_channels as usize;
        if frame == 0 || self.data.len() % frame != 0 {
            return Err(CdrError::Range { field: "data length", value: self.data.len() as u64 });
        }
        Ok(self.data.chunks_exact(2).map(|b| i16::from_le_bytes([b[0], b[1]])).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_audio_has_the_documented_bytes() {
        let mut b = Vec::new();
        let t = Time { sec: 1_700_000_123, nanosec: 456_789 };
        RawAudio::encode_pcm_s16(t, [1i16, -1, 0x1234].into_iter(), 48_000, 1, &mut b);
        let mut want = super::super::CDR_LE.to_vec();
        want.extend_from_slice(&1_700_000_123i32.to_le_bytes());
        want.extend_from_slice(&456_789u32.to_le_bytes());
        want.extend_from_slice(&6u32.to_le_bytes());
        want.extend_from_slice(&[1, 0, 0xff, 0xff, 0x34, 0x12]);
        want.extend_from_slice(&[0, 0]); // the string's length is aligned to 4 (offset 20)
        want.extend_from_slice(&8u32.to_le_bytes()); // "pcm-s16" + NUL
        want.extend_from_slice(b"pcm-s16\0");
        want.extend_from_slice(&48_000u32.to_le_bytes());
        want.extend_from_slice(&1u32.to_le_bytes());
        assert_eq!(b, want);
        let m = RawAudio::decode(&b).unwrap();
        assert_eq!((m.timestamp, m.pcm_s16().unwrap()), (t, vec![1, -1, 0x1234]));
        let mut again = Vec::new();
        m.encode(&mut again);
        assert_eq!(again, b);
    }

    #[test]
    fn the_string_after_any_data_length_is_aligned() {
        for n in 0..=5usize {
            let mut b = Vec::new();
            RawAudio::encode_pcm_s16(Time::default(), std::iter::repeat(7i16).take(n), 8000, 1, &mut b);
            let len_at = (12 + 2 * n).next_multiple_of(4);
            assert_eq!(&b[4 + len_at..4 + len_at + 4], &8u32.to_le_bytes(), "{n} samples");
            assert_eq!(b.len(), 4 + len_at + 4 + 8 + 4 + 4);
            assert_eq!(RawAudio::decode(&b).unwrap().pcm_s16().unwrap(), vec![7; n]);
        }
    }

    #[test]
    fn decoding_refuses_bad_payloads_by_name() {
        let mut b = Vec::new();
        RawAudio::encode_pcm_s16(Time::default(), [1i16, 2, 3].into_iter(), 8000, 2, &mut b);
        let m = RawAudio::decode(&b).unwrap();
        assert_eq!(m.pcm_s16(), Err(CdrError::Range { field: "data length", value: 6 }));
        let other = RawAudio { format: "g711-ulaw".into(), ..m };
        assert!(other.pcm_s16().unwrap_err().to_string().contains("\"g711-ulaw\""));
        for cut in [3, 10, b.len() - 1] {
            assert!(RawAudio::decode(&b[..cut]).is_err(), "cut at {cut}");
        }
        let mut late = b.clone();
        late[8..12].copy_from_slice(&1_000_000_000u32.to_le_bytes());
        assert_eq!(
            RawAudio::decode(&late),
            Err(CdrError::Range { field: "timestamp.nanosec", value: 1_000_000_000 })
        );
    }

    #[test]
    fn the_topic_is_beside_the_audio_topic() {
        assert_eq!(topic("left-ear.2"), "/bass/left_ear_2/raw_audio");
        assert_eq!(
            super::super::Topics::of("left-ear.2").audio.rsplit_once('/').unwrap().0,
            topic("left-ear.2").rsplit_once('/').unwrap().0
        );
    }

    #[test]
    fn the_definition_is_rosbag2_form_with_its_one_dependency() {
        let parts: Vec<&str> = RAW_AUDIO_DEFINITION.split(&format!("\n{}\n", super::super::RULE)).collect();
        assert_eq!(parts.len(), 2);
        assert!(parts[1].starts_with("MSG: builtin_interfaces/Time\n"), "{:?}", parts[1]);
    }
}
