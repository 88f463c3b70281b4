//! ALSA capture: device hints, format negotiation, non-blocking reads driven by `poll` on
//! the PCM's descriptors and the stop eventfd, timestamps from ALSA's status, overrun
//! recovery and device-loss detection.
//!
//! Negotiation: interleaved read access; exactly the requested channels and rate (ALSA's
//! resampler is disabled, so an unsupported rate is an error naming what the device
//! supports); the first of S32_LE, S24_LE, S24_3LE, FLOAT_LE, S16_LE that the device
//! accepts (or the one the request forces); period = nFramesPerChunk (nearest the device
//! allows: chunks are assembled from whatever the reads return); a buffer of at least four
//! periods and 200 ms.

use std::time::Duration;

use alsa::pcm::{Access, Frames, HwParams, TstampType, PCM};
use alsa::poll::Descriptors;
use alsa::{Direction, ValueOr};
use bassport::control::DeviceInfo;
use bassport::format::error_code;
use bassport::sys::monotonic_ns;

use super::{Capture, ReadEvent, StopSignal};
use crate::convert::{to_s32, SampleFormat};
use crate::os;

/// How long one read waits for data before reporting [`ReadEvent::Idle`].
const POLL_SLICE: Duration = Duration::from_millis(50);

/// ALSA capture PCMs from the configuration's hints (`snd_device_name_hint`).
pub fn list() -> Vec<DeviceInfo> {
    let Ok(hints) = alsa::device_name::HintIter::new_str(None, "pcm") else {
        return Vec::new();
    };
    hints
        .filter(|h| h.direction != Some(Direction::Playback))
        .filter_map(|h| {
            let name = h.name?;
            let description =
                h.desc.unwrap_or_default().lines().map(str::trim).collect::<Vec<_>>().join(" / ");
            Some(DeviceInfo { name, description })
        })
        .collect()
}

/// Why a device could not be opened or configured.
#[derive(Debug)]
pub struct OpenError {
    /// `format::error_code` for the port (CONFIG).
    pub code: u32,
    /// The message for the client and the port.
    pub message: String,
    /// The PCM was busy (EBUSY): another stream, perhaps our own running capture, holds it.
    pub busy: bool,
}

fn errno_text(e: &alsa::Error) -> String {
    let n = e.errno().abs();
    format!("{} failed: {}", e.func(), std::io::Error::from_raw_os_error(n))
}

/// A configured ALSA capture PCM.
pub struct AlsaDevice {
    pcm: PCM,
    name: String,
    format: SampleFormat,
    channels: usize,
    rate: u32,
    frame_bytes: usize,
    bytes: Vec<u8>,
    buffer: Frames,
    /// Where the frame after the last read lies by that read's estimated stamp, while the
    /// reads follow one another without a wait ([`continued_stamp`]).
    continued_ns: Option<u64>,
}

/// The stamp of a read's first frame on a device without timestamps (`now − avail`): that
/// estimate is late by the time since the frames arrived, which for a read that empties what
/// a previous read of the same wake-up left behind (ALSA's jack plugin: 480 frames, then the
/// period's last 32) is the whole time the thread spent in between, up to a period or more on
/// a loaded machine. The previous read's stamp plus its frames is as late as that read's
/// stamp only, and both are never early, so the earlier of the two is kept. Not carried
/// across a wait: chained for ever, the nominal rate's error would accumulate.
fn continued_stamp(fresh_ns: u64, estimated: bool, continued_ns: Option<u64>) -> u64 {
    match continued_ns {
        Some(c) if estimated => fresh_ns.min(c),
        _ => fresh_ns,
    }
}

/// Parameters for [`open`].
pub struct OpenParams<'a> {
    /// ALSA PCM name.
    pub name: &'a str,
    /// Exact rate (Hz).
    pub rate: u32,
    /// Channels.
    pub channels: u32,
    /// Preferred period (frames).
    pub period: u32,
    /// Forced sample format, if any.
    pub format: Option<SampleFormat>,
}

/// Opens and configures `p.name` for capture.
pub fn open(p: &OpenParams<'_>) -> Result<AlsaDevice, OpenError> {
    let name = p.name;
    let config = |message: String| OpenError { code: error_code::CONFIG, message, busy: false };
    let pcm = PCM::new(name, Direction::Capture, true).map_err(|e| OpenError {
        busy: e.errno().abs() == libc::EBUSY,
        ..config(format!("cannot open ALSA capture device {name:?}: {}", errno_text(&e)))
    })?;
    let alsa_err =
        |what: &str, e: alsa::Error| config(format!("device {name:?}: {what}: {}", errno_text(&e)));
    let format;
    let (period, buffer);
    {
        let hw = HwParams::any(&pcm).map_err(|e| alsa_err("reading its hardware parameters", e))?;
        hw.set_access(Access::RWInterleaved)
            .map_err(|_| config(format!("device {name:?} does not support interleaved read access")))?;
        if hw.set_channels(p.channels).is_err() {
            let (lo, hi) = (hw.get_channels_min().unwrap_or(0), hw.get_channels_max().unwrap_or(0));
            return Err(config(format!(
                "{} channels are not supported by device {name:?} (it supports {})",
                p.channels,
                range(lo, hi, "")
            )));
        }
        let _ = hw.set_rate_resample(false);
        if hw.set_rate(p.rate, ValueOr::Nearest).is_err() || hw.get_rate().ok() != Some(p.rate) {
            let (lo, hi) = (hw.get_rate_min().unwrap_or(0), hw.get_rate_max().unwrap_or(0));
            return Err(config(format!(
                "sample rate {} Hz is not supported by device {name:?} (it supports {})",
                p.rate,
                range(lo, hi, " Hz")
            )));
        }
        let supported: Vec<SampleFormat> =
            SampleFormat::PREFERENCE.into_iter().filter(|f| hw.test_format(f.alsa()).is_ok()).collect();
        let names = |v: &[SampleFormat]| v.iter().map(|f| f.name()).collect::<Vec<_>>().join(", ");
        format = match p.format {
            Some(f) if supported.contains(&f) => f,
            Some(f) => {
                return Err(config(format!(
                    "sample format {} is not supported by device {name:?} (of the formats bass accepts it supports: {})",
                    f.name(),
                    if supported.is_empty() { "none".to_string() } else { names(&supported) }
                )))
            }
            None => *supported.first().ok_or_else(|| {
                config(format!(
                    "device {name:?} supports none of the sample formats bass accepts ({})",
                    names(&SampleFormat::PREFERENCE)
                ))
            })?,
        };
        hw.set_format(format.alsa())
            .map_err(|e| alsa_err(&format!("setting format {}", format.name()), e))?;
        let want_period = Frames::from(p.period.max(1));
        period = hw
            .set_period_size_near(want_period, ValueOr::Nearest)
            .map_err(|e| alsa_err(&format!("setting a period of {} frames", p.period), e))?;
        let min_buffer = (period * 4).max(Frames::from(p.rate / 5));
        let periods = (min_buffer + period - 1) / period.max(1);
        buffer = hw
            .set_buffer_size_near(period * periods)
            .map_err(|e| alsa_err(&format!("setting a buffer of {} frames", period * periods), e))?;
        pcm.hw_params(&hw).map_err(|e| alsa_err("applying the hardware parameters", e))?;
    }
    {
        let sw = pcm.sw_params_current().map_err(|e| alsa_err("reading its software parameters", e))?;
        let _ = sw.set_avail_min(period.max(1));
        // Started explicitly by `start()`; never stop on our own (overruns are reported).
        let _ = sw.set_start_threshold(buffer.max(1));
        let _ = sw.set_tstamp_mode(true);
        let _ = sw.set_tstamp_type(TstampType::Monotonic);
        pcm.sw_params(&sw).map_err(|e| alsa_err("applying the software parameters", e))?;
    }
    tracing::info!(
        device = name,
        format = format.name(),
        rate = p.rate,
        channels = p.channels,
        period,
        buffer,
        "ALSA device configured"
    );
    let channels = p.channels as usize;
    let frame_bytes = format.bytes() * channels;
    Ok(AlsaDevice {
        pcm,
        name: name.to_owned(),
        format,
        channels,
        rate: p.rate,
        frame_bytes,
        bytes: vec![0; frame_bytes * (period.max(1) as usize).max(p.period as usize)],
        buffer,
        continued_ns: None,
    })
}

fn range(lo: u32, hi: u32, unit: &str) -> String {
    if lo == hi {
        format!("only {lo}{unit}")
    } else {
        format!("{lo}..{hi}{unit}")
    }
}

fn ts_ns(t: libc::timespec) -> u64 {
    (t.tv_sec as u64).wrapping_mul(1_000_000_000).wrapping_add(t.tv_nsec as u64)
}

impl AlsaDevice {
    fn lost(&self, what: &str, e: &alsa::Error) -> ReadEvent {
        ReadEvent::Failed {
            code: error_code::DEVICE_LOST,
            message: format!("device {:?} lost: {what}: {}", self.name, errno_text(e)),
        }
    }

    /// Recovers from an overrun or a suspend: prepare and restart the stream.
    fn recover(&self, e: &alsa::Error) -> ReadEvent {
        tracing::warn!(device = %self.name, "overrun ({}); restarting the stream", errno_text(e));
        if let Err(e2) = self.pcm.prepare() {
            return self.lost("snd_pcm_prepare after an overrun", &e2);
        }
        if let Err(e2) = self.pcm.start() {
            return self.lost("snd_pcm_start after an overrun", &e2);
        }
        ReadEvent::Xrun
    }

    /// CLOCK_MONOTONIC of the oldest unread frame: the status timestamp minus the delay
    /// where the device gives a timestamp (hardware), else estimated as now minus the frames
    /// waiting (`snd_pcm_avail_update`; plugins such as `jack` report neither in their
    /// status). `None` when more frames wait than the buffer holds: an overrun the device
    /// did not report.
    fn oldest_frame_time(&self) -> Option<(u64, bool)> {
        let to_ns =
            |frames: Frames| (frames.max(0) as u64).saturating_mul(1_000_000_000) / u64::from(self.rate);
        let avail = self.pcm.avail_update().unwrap_or(0);
        let now = monotonic_ns();
        if avail > self.buffer {
            return None;
        }
        if let Ok(st) = self.pcm.status() {
            let t = ts_ns(st.get_htstamp());
            let plausible = t != 0 && t <= now + 1_000_000_000 && now - t.min(now) < 5_000_000_000;
            if plausible {
                return Some((t.saturating_sub(to_ns(st.get_delay())), false));
            }
        }
        Some((now.saturating_sub(to_ns(avail)), true))
    }
}

impl Capture for AlsaDevice {
    fn start(&mut self) -> Result<(), String> {
        self.pcm.start().map_err(|e| format!("device {:?}: {}", self.name, errno_text(&e)))
    }

    fn read(&mut self, out: &mut [i32], max_frames: usize, stop: &StopSignal) -> ReadEvent {
        let frames = max_frames.min(self.bytes.len() / self.frame_bytes).min(out.len() / self.channels);
        let mut polled = false;
        loop {
            if stop.is_set() {
                return ReadEvent::Stopped;
            }
            let Some((fresh_ns, estimated)) = self.oldest_frame_time() else {
                self.continued_ns = None;
                let e = alsa::Error::new(
                    "snd_pcm_status (more frames available than the buffer holds)",
                    -libc::EPIPE,
                );
                return self.recover(&e);
            };
            let first_ns = continued_stamp(fresh_ns, estimated, self.continued_ns);
            let got = self.pcm.io_bytes().readi(&mut self.bytes[..frames * self.frame_bytes]);
            match got {
                Ok(n) if n > 0 => {
                    self.continued_ns = estimated
                        .then(|| first_ns + (n as u64).saturating_mul(1_000_000_000) / u64::from(self.rate));
                    let samples = n * self.channels;
                    to_s32(self.format, &self.bytes[..n * self.frame_bytes], &mut out[..samples]);
                    return ReadEvent::Frames {
                        frames: n,
                        first_mono_ns: first_ns,
                        time_estimated: estimated,
                        observed_mono_ns: first_ns,
                        late: false,
                    };
                }
                Ok(_) => {}
                Err(e) => match e.errno().abs() {
                    libc::EAGAIN => {}
                    libc::EPIPE | libc::ESTRPIPE => {
                        self.continued_ns = None;
                        return self.recover(&e);
                    }
                    _ => return self.lost("snd_pcm_readi", &e),
                },
            }
            // A wait: the next read's stamp is its own.
            self.continued_ns = None;
            if polled {
                return ReadEvent::Idle;
            }
            // Nothing yet: wait on the PCM's descriptors and the stop eventfd.
            let mut fds = match self.pcm.get() {
                Ok(f) => f,
                Err(e) => return self.lost("snd_pcm_poll_descriptors", &e),
            };
            fds.push(os::pollin(stop.fd()));
            if let Err(e) = os::poll(&mut fds, Some(POLL_SLICE)) {
                return ReadEvent::Failed { code: error_code::INTERNAL, message: format!("poll: {e}") };
            }
            let last = fds.len() - 1;
            if fds[last].revents != 0 {
                return ReadEvent::Stopped;
            }
            match self.pcm.revents(&fds[..last]) {
                Ok(flags) if flags.contains(alsa::poll::Flags::ERR) => {
                    if let alsa::pcm::State::Disconnected = self.pcm.state() {
                        return ReadEvent::Failed {
                            code: error_code::DEVICE_LOST,
                            message: format!("device {:?} lost: disconnected (ENODEV)", self.name),
                        };
                    }
                }
                Ok(_) => {}
                Err(e) if e.errno().abs() == libc::ENODEV => {
                    return self.lost("snd_pcm_poll_descriptors_revents", &e)
                }
                Err(_) => {}
            }
            polled = true;
        }
    }

    fn format_name(&self) -> &'static str {
        self.format.name()
    }
}

#[cfg(test)]
mod tests {
    use super::continued_stamp;

    /// The jack plugin's pattern, from a bassd trace: a wake-up reads 480 frames stamped
    /// 366.450 ms, the period's last 32 are read 10.97 ms later (`now − avail` says 377.422 ms)
    /// while they arrived with the others (366.450 + 10.000 ms).
    #[test]
    fn a_read_that_follows_a_read_without_a_wait_keeps_the_earlier_stamp() {
        let first = 366_450_028;
        let continued = first + 10_000_000;
        assert_eq!(continued_stamp(377_422_432, true, Some(continued)), continued);
        // A fresh estimate earlier than the continuation wins (the previous read's was late).
        assert_eq!(continued_stamp(376_000_000, true, Some(continued)), 376_000_000);
        // After a wait, or where the device gives timestamps, the read's own stamp stands.
        assert_eq!(continued_stamp(377_422_432, true, None), 377_422_432);
        assert_eq!(continued_stamp(377_422_432, false, Some(continued)), 377_422_432);
    }
}
