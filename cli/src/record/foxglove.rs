//! The `foxglove_msgs/msg/RawAudio` channel of `bass record --format mcap --foxglove-audio`
//! ([`basskit::ros2::foxglove`]), for Foxglove's Audio panel, and its verification by
//! `bass record --check`.
//!
//! Every `AudioDataStamped` message of such a recording is followed by one RawAudio message on
//! `/bass/<broker>/raw_audio` with the same MCAP sequence number, log time and stamp, holding
//! the same frames and channels as `pcm-s16`: each sample rounded to 16 bits as `--bits 16`
//! rounds it in a WAV ([`super::convert`]: half up, saturating). Frames the recorder lost are in
//! neither message; GAP frames are zeros in both.

use std::collections::{BTreeMap, BTreeSet};
use std::io::{Seek, Write};

use basskit::ros2::foxglove::{self, RawAudio, PCM_S16, RAW_AUDIO, RAW_AUDIO_DEFINITION};
use basskit::ros2::{self, AudioDataStamped, Time};

use super::convert;

/// A captured (left-justified S32) sample as 16 bits, exactly as `--bits 16` writes it.
pub fn to_s16(s: i32) -> i16 {
    // convert(_, 16) is in -32768..=32767.
    convert(s, 16) as i16
}

/// The RawAudio channel of an MCAP recording being written.
pub(super) struct Channel {
    /// The MCAP channel id.
    pub id: u16,
    /// Its topic.
    pub topic: String,
    /// Messages written on it.
    pub messages: u64,
    rate: u32,
    channels: u32,
}

impl Channel {
    /// Adds the schema and the channel (offering `qos`, rosbag2's `offered_qos_profiles`) for
    /// `channels` recorded channels of broker `broker` at `rate` Hz.
    pub fn add<W: Write + Seek>(
        w: &mut mcap::Writer<W>,
        broker: &str,
        rate: u32,
        channels: usize,
        qos: &str,
    ) -> Result<Channel, mcap::McapError> {
        let schema = w.add_schema(RAW_AUDIO, ros2::SCHEMA_ENCODING, RAW_AUDIO_DEFINITION.as_bytes())?;
        let topic = foxglove::topic(broker);
        let meta = BTreeMap::from([("offered_qos_profiles".to_string(), qos.to_string())]);
        let id = w.add_channel(schema, &topic, ros2::MESSAGE_ENCODING, &meta)?;
        let channels = u32::try_from(channels).unwrap_or(u32::MAX);
        Ok(Channel { id, topic, messages: 0, rate, channels })
    }

    /// The message of one run: `samples` (interleaved S32 frames) as 16 bits, stamped `stamp`.
    pub fn encode(&self, stamp: Time, samples: &[i32], out: &mut Vec<u8>) {
        let s16 = samples.iter().map(|&s| to_s16(s));
        RawAudio::encode_pcm_s16(stamp, s16, self.rate, self.channels, out);
    }
}

fn time(t: Time) -> String {
    format!("{}.{:09}", t.sec, t.nanosec)
}

/// What `bass record --check` holds the RawAudio messages of a file against: each one the
/// `pcm-s16` conversion of the audio message with its sequence number just before it (same
/// stamp, same samples rounded to 16 bits), one per audio message, at the recording's rate
/// and channels.
#[derive(Default)]
pub(super) struct Check {
    /// The last audio message and its sequence number.
    last_audio: Option<(u32, AudioDataStamped)>,
    /// RawAudio messages read.
    pub messages: u64,
    /// Every (sample_rate, number_of_channels) the messages hold.
    shapes: BTreeSet<(u32, u32)>,
    problems: Vec<String>,
}

impl Check {
    /// An audio message `seq` of the file.
    pub fn audio(&mut self, seq: u32, msg: AudioDataStamped) {
        self.last_audio = Some((seq, msg));
    }

    /// A RawAudio message `seq` of the file.
    pub fn raw(&mut self, seq: u32, payload: &[u8]) {
        self.messages += 1;
        let m = match RawAudio::decode(payload) {
            Ok(m) => m,
            Err(e) => return self.problems.push(format!("RawAudio message {seq}: {e}")),
        };
        let Some((_, audio)) = self.last_audio.take().filter(|(s, _)| *s == seq) else {
            return self.problems.push(format!(
                "RawAudio message {seq} has no audio message with its sequence number before it"
            ));
        };
        if m.timestamp != audio.header.stamp {
            self.problems.push(format!(
                "RawAudio message {seq}: timestamp {}, its audio message's stamp is {}",
                time(m.timestamp),
                time(audio.header.stamp)
            ));
        }
        self.shapes.insert((m.sample_rate, m.number_of_channels));
        let (pcm, s32) = match (m.pcm_s16(), audio.samples()) {
            (Ok(p), Ok(s)) => (p, s),
            (Err(e), _) => return self.problems.push(format!("RawAudio message {seq}: {e}")),
            (_, Err(e)) => return self.problems.push(format!("audio message {seq}: {e}")),
        };
        if pcm.len() != s32.len() {
            return self.problems.push(format!(
                "RawAudio message {seq}: {} samples, its audio message {}",
                pcm.len(),
                s32.len()
            ));
        }
        if let Some(i) = (0..pcm.len()).find(|&i| pcm[i] != to_s16(s32[i])) {
            self.problems.push(format!(
                "RawAudio message {seq}: sample {i} is {}; the audio message's {} is {} in 16 bits",
                pcm[i],
                s32[i],
                to_s16(s32[i])
            ));
        }
    }

    /// The problems found, with the count against `audio_messages` and the messages' rate and
    /// channels against the recording's (`rate`, `channels`). None for a file without RawAudio
    /// messages.
    pub fn finish(self, audio_messages: usize, rate: u32, channels: usize) -> Vec<String> {
        let mut v = self.problems;
        if self.messages == 0 {
            return v;
        }
        if self.messages != audio_messages as u64 {
            v.push(format!("{} RawAudio messages for {audio_messages} audio messages", self.messages));
        }
        let want = (rate, channels as u32);
        if let Some((r, c)) = self.shapes.iter().find(|&&s| s != want) {
            v.push(format!(
                "a RawAudio message of {r} Hz and {c} channels; the recording's are {} Hz and {} channels ({PCM_S16})",
                want.0, want.1
            ));
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use basskit::ros2::Header;

    fn audio(stamp: Time, samples: &[i32]) -> AudioDataStamped {
        let mut b = Vec::new();
        AudioDataStamped::encode_samples(&Header { stamp, frame_id: String::new() }, samples, &mut b);
        AudioDataStamped::decode(&b).unwrap()
    }

    #[test]
    fn samples_become_16_bits_as_the_wav_path_rounds_them() {
        // Half up, saturating: 0x7FFF_8000 would round to 0x8000.
        assert_eq!(to_s16(0x0001_7FFF), 1);
        assert_eq!(to_s16(0x0001_8000), 2);
        assert_eq!(to_s16(-0x8000), 0);
        assert_eq!(to_s16(-0x8001), -1);
        assert_eq!(to_s16(0x7FFF_8000), i16::MAX);
        assert_eq!(to_s16(i32::MAX), i16::MAX);
        assert_eq!(to_s16(i32::MIN), i16::MIN);
        for s in [0, 1, -1, 0x1234_5678, -0x1234_5678, i32::MAX, i32::MIN] {
            assert_eq!(i32::from(to_s16(s)), convert(s, 16), "{s:#x}");
        }
    }

    #[test]
    fn a_channel_message_holds_the_run_in_16_bits() {
        let ch = Channel { id: 4, topic: "/bass/x/raw_audio".into(), messages: 0, rate: 8000, channels: 2 };
        let stamp = Time { sec: 5, nanosec: 7 };
        let mut b = Vec::new();
        ch.encode(stamp, &[0x0001_8000, -0x8001, 0, 0x7FFF_FFFF], &mut b);
        let m = RawAudio::decode(&b).unwrap();
        assert_eq!(m.timestamp, stamp);
        assert_eq!((m.sample_rate, m.number_of_channels, m.format.as_str()), (8000, 2, PCM_S16));
        assert_eq!(m.pcm_s16().unwrap(), vec![2, -1, 0, i16::MAX]);
    }

    #[test]
    fn the_check_passes_the_conversion_and_names_every_disagreement() {
        let ch = Channel { id: 4, topic: String::new(), messages: 0, rate: 8000, channels: 1 };
        let t = Time { sec: 1, nanosec: 2 };
        let samples = [0x0001_8000, 5 << 16];
        let mut good = Vec::new();
        ch.encode(t, &samples, &mut good);
        let mut c = Check::default();
        c.audio(3, audio(t, &samples));
        c.raw(3, &good);
        assert_eq!(c.finish(1, 8000, 1), Vec::<String>::new());

        type Break<'a> = Box<dyn Fn(&mut Check) + 'a>;
        let cases: [(&str, Break); 5] = [
            (
                "sample 0 is 1",
                Box::new(|c| {
                    let mut b = Vec::new();
                    RawAudio::encode_pcm_s16(t, [1i16, 5].into_iter(), 8000, 1, &mut b);
                    c.raw(3, &b);
                }),
            ),
            (
                "timestamp 1.000000003",
                Box::new(|c| {
                    let mut b = Vec::new();
                    ch.encode(Time { sec: 1, nanosec: 3 }, &samples, &mut b);
                    c.raw(3, &b);
                }),
            ),
            ("no audio message with its sequence number", Box::new(|c| c.raw(4, &good))),
            (
                "2 RawAudio messages for 1",
                Box::new(|c| {
                    c.raw(3, &good);
                    c.raw(3, &good);
                }),
            ),
            (
                "of 48000 Hz",
                Box::new(|c| {
                    let mut b = Vec::new();
                    Channel { id: 4, topic: String::new(), messages: 0, rate: 48_000, channels: 1 }
                        .encode(t, &samples, &mut b);
                    c.raw(3, &b);
                }),
            ),
        ];
        for (want, f) in cases {
            let mut c = Check::default();
            c.audio(3, audio(t, &samples));
            f(&mut c);
            let p = c.finish(1, 8000, 1);
            assert!(p.iter().any(|p| p.contains(want)), "{want:?} not in {p:?}");
        }
    }
}
