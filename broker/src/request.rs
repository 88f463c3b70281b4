//! Checks an Acquire request before anything running is touched.
//!
//! A request that fails here (zero or overflowing sizes, a window above the memory cap, a
//! malformed device name, an unknown simulated device or sample format) is refused and the
//! running acquisition keeps running: nothing is lost. Whether an ALSA device exists and
//! supports the rate, format and channels is only known by opening it, which needs the
//! running acquisition stopped first (a device can usually be opened once); that failure
//! leaves the port in the Error state with the message.

use basskit::limits::Holder;
use bassport::control::AcquireRequest;
use bassport::format::{Geometry, DEVICE_LEN};

use crate::convert::SampleFormat;
use crate::device::sim::{SimKind, DEVICES};

pub use bassport::format::MAX_SAMPLE_RATE;

/// Operator-set bounds a client's Acquire cannot exceed (bassd `--min-chunk-us`,
/// `--max-rate`, `--max-channels`, `--max-window-s`, `--max-port-bytes`): basskit's, which the
/// mirror shares.
pub use basskit::limits::Limits;

/// Which device a request names.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DeviceKind {
    /// A simulated device.
    Sim(SimKind),
    /// A simulated card with its own clock sampling the shared field (`sim:field?...`).
    Field(crate::device::field::FieldParams),
    /// An ALSA PCM name.
    Alsa(String),
    /// A WAV file replayed (`sim:file:PATH`, `sim:file-renumber:PATH`, `sim:file-loop:PATH`;
    /// see `device::file`).
    File {
        /// The file.
        path: std::path::PathBuf,
        /// At the recorded indices, renumbered, or in a loop.
        mode: crate::device::file::Mode,
    },
}

/// A request that passed the checks.
#[derive(Clone, Debug)]
pub struct Checked {
    /// Port geometry.
    pub geometry: Geometry,
    /// The device.
    pub device: DeviceKind,
    /// Forced sample format.
    pub format: Option<SampleFormat>,
    /// Size of the port file (bytes).
    pub port_bytes: u64,
    /// The master device's channels (the port's first ones; all of them without followers).
    pub master_channels: u32,
    /// The follower devices, in port channel order.
    pub followers: Vec<CheckedFollower>,
}

/// A follower device that passed the checks.
#[derive(Clone, Debug)]
pub struct CheckedFollower {
    /// Its name as requested.
    pub name: String,
    /// The device.
    pub device: DeviceKind,
    /// Its channels.
    pub channels: u32,
}

/// Most devices in one acquisition (the master and its followers).
pub const MAX_DEVICES: usize = 8;

/// Checks `r` against the format's limits, the operator's bounds and the broker's memory cap.
pub fn check(r: &AcquireRequest, limits: &Limits) -> Result<Checked, String> {
    let device = device_kind(&r.device)?;
    let format = match &r.format {
        None => None,
        Some(f) => Some(SampleFormat::from_name(f).ok_or_else(|| {
            let known: Vec<&str> = SampleFormat::PREFERENCE.iter().map(|f| f.name()).collect();
            format!("unknown sample format {f:?} (use one of {})", known.join(", "))
        })?),
    };
    if r.sample_rate > MAX_SAMPLE_RATE {
        return Err(format!("sampleRate = {} Hz (must be 1..={MAX_SAMPLE_RATE})", r.sample_rate));
    }
    let followers = check_followers(r)?;
    let channels = followers.iter().try_fold(r.channels, |sum, f| sum.checked_add(f.channels));
    let channels = channels.filter(|&c| followers.is_empty() || c <= 64).ok_or_else(|| {
        let each: Vec<String> = followers.iter().map(|f| f.channels.to_string()).collect();
        format!(
            "channels = {} (master) + {} (followers): more than the port's 64",
            r.channels,
            each.join(" + ")
        )
    })?;
    let geometry = Geometry {
        channels,
        sample_rate: r.sample_rate,
        frames_per_chunk: r.frames_per_chunk,
        chunks_on_port: r.chunks_on_port,
    };
    let port_bytes = limits.check(&geometry, Holder::Broker)?;
    Ok(Checked { geometry, device, format, port_bytes, master_channels: r.channels, followers })
}

/// The followers of `r`, checked (names, channels, no device twice).
fn check_followers(r: &AcquireRequest) -> Result<Vec<CheckedFollower>, String> {
    if r.followers.len() + 1 > MAX_DEVICES {
        return Err(format!(
            "{} follower devices: at most {} devices in one acquisition",
            r.followers.len(),
            MAX_DEVICES
        ));
    }
    if !r.followers.is_empty() && r.channels == 0 {
        return Err("channels = 0 (the master's)".into());
    }
    let mut out = Vec::new();
    for (i, f) in r.followers.iter().enumerate() {
        let device = device_kind(&f.device).map_err(|e| format!("follower {}: {e}", i + 1))?;
        if !matches!(device, DeviceKind::Sim(_) | DeviceKind::Field(_) | DeviceKind::Alsa(_)) {
            return Err(format!(
                "follower {} {:?}: a replayed recording cannot be a follower",
                i + 1,
                f.device
            ));
        }
        let simulated = !matches!(device, DeviceKind::Alsa(_));
        let twice = f.device == r.device || r.followers[..i].iter().any(|g| g.device == f.device);
        if twice && !simulated {
            return Err(format!("device {:?} named twice in one acquisition", f.device));
        }
        let channels = if f.channels == 0 { r.channels } else { f.channels };
        out.push(CheckedFollower { name: f.device.clone(), device, channels });
    }
    Ok(out)
}

/// The device `name` names, checked.
fn device_kind(name: &str) -> Result<DeviceKind, String> {
    if name.is_empty() {
        return Err("device name is empty".into());
    }
    if name.len() >= DEVICE_LEN {
        return Err(format!("device name of {} bytes is too long (at most {})", name.len(), DEVICE_LEN - 1));
    }
    if name.chars().any(char::is_control) {
        return Err(format!("device name {name:?} contains control characters"));
    }
    Ok(match name.strip_prefix("sim:") {
        Some(s) if s == "field" || s.starts_with("field?") => {
            DeviceKind::Field(crate::device::field::parse(&s["field".len()..])?)
        }
        Some(s) => match file_device(s) {
            Some(file) => file?,
            None => DeviceKind::Sim(SimKind::from_name(s).ok_or_else(|| {
                let known: Vec<String> = DEVICES.iter().map(|(k, _)| format!("sim:{}", k.name())).collect();
                format!("unknown simulated device {name:?} (available: {}, sim:field?...)", known.join(", "))
            })?),
        },
        None => DeviceKind::Alsa(name.to_owned()),
    })
}

/// `file:PATH`, `file-renumber:PATH` or `file-loop:PATH` (after `sim:`); `None` for any other name.
fn file_device(s: &str) -> Option<Result<DeviceKind, String>> {
    use crate::device::file::Mode;
    let (mode, path) = [Mode::Recorded, Mode::Renumber, Mode::Loop]
        .into_iter()
        .find_map(|m| s.strip_prefix(m.prefix()).map(|p| (m, p)))?;
    if path.is_empty() {
        return Some(Err(format!(
            "sim:{} needs the WAV file, e.g. sim:{}/data/rec.wav",
            mode.prefix(),
            mode.prefix()
        )));
    }
    // Relative to what? bassd's working directory is not the client's (a service runs in /),
    // so a relative name is refused for what it is, before the device policy would refuse it
    // for not matching the operator's absolute patterns. The command-line tools (`bass
    // acquire`, `bassd --acquire`) make a relative name absolute against their own directory.
    if std::path::Path::new(path).is_relative() {
        return Some(Err(format!(
            "relative path {path:?} in sim:{}{path}: give an absolute path (bassd cannot know \
             the client's working directory; `bass acquire` makes a relative path absolute \
             against its own)",
            mode.prefix()
        )));
    }
    Some(Ok(DeviceKind::File { path: path.into(), mode }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn req(device: &str, rate: u32, nfpc: u32, ncop: u32, ch: u32) -> AcquireRequest {
        AcquireRequest {
            device: device.into(),
            sample_rate: rate,
            frames_per_chunk: nfpc,
            chunks_on_port: ncop,
            channels: ch,
            format: None,
            followers: Vec::new(),
        }
    }

    #[test]
    fn the_seed_defaults_pass() {
        let c = check(&AcquireRequest::default(), &Limits { max_port_bytes: 1 << 30, ..Limits::default() })
            .unwrap();
        assert_eq!(c.device, DeviceKind::Alsa("hw:1,0".into()));
        assert_eq!(c.geometry.frames_per_chunk, 2205);
    }

    #[test]
    fn bad_requests_name_the_bad_value() {
        let cases = [
            (req("sim:sine", 48000, 0, 20, 2), "nFramesPerChunk = 0"),
            (req("sim:sine", 48000, 64, 0, 2), "nChunksOnPort = 0"),
            (req("sim:sine", 0, 64, 20, 2), "sampleRate = 0"),
            (req("sim:sine", 48000, 64, 20, 0), "channels = 0"),
            (req("sim:sine", 48000, 64, 20, 65), "channels = 65"),
            (req("sim:sine", 48000, u32::MAX, u32::MAX, 64), "exceeds"),
            (req("sim:sine", 48000, 1 << 20, 64, 2), "memory cap"),
            (req("sim:nope", 48000, 64, 20, 2), "unknown simulated device"),
            (req("", 48000, 64, 20, 2), "empty"),
            (req("hw:0\n", 48000, 64, 20, 2), "control characters"),
            (req("sim:sine", 10_000_000, 64, 20, 2), "sampleRate = 10000000"),
        ];
        for (r, want) in cases {
            let e = check(&r, &Limits { max_port_bytes: 64 << 20, ..Limits::default() }).unwrap_err();
            assert!(e.contains(want), "{r:?}: {e:?} does not mention {want:?}");
        }
        let mut forced = req("sim:sine", 48000, 64, 20, 2);
        forced.format = Some("U8".into());
        assert!(check(&forced, &Limits::default()).unwrap_err().contains("unknown sample format"));
    }

    #[test]
    fn operator_bounds_refuse_a_starving_request_and_widened_bounds_accept_it() {
        let starving = req("sim:pattern", 768_000, 1, 4096, 64);
        let e = check(&starving, &Limits::default()).unwrap_err();
        assert!(e.contains("--max-rate"), "{e}");
        let wide_rate = Limits { max_rate: 768_000, ..Limits::default() };
        let e = check(&starving, &wide_rate).unwrap_err();
        assert!(e.contains("--max-channels"), "{e}");
        let wide_ch = Limits { max_channels: 64, ..wide_rate };
        let e = check(&starving, &wide_ch).unwrap_err();
        assert!(e.contains("minimum chunk duration of 500 µs"), "{e}");
        let wide = Limits { min_chunk_us: 0, ..wide_ch };
        assert!(check(&starving, &wide).is_ok());
        let long = req("sim:pattern", 8000, 8000, 3601, 1);
        assert!(check(&long, &Limits::default()).unwrap_err().contains("--max-window-s"));
        assert!(check(&req("sim:pattern", 8000, 4, 10, 1), &Limits::default()).is_ok());
    }
}
