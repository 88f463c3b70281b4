//! The command-line vocabulary bass's programs share — `bassd`, `bass`, `bass-bridge` —, so
//! that a value means the same everywhere: durations ([`parse_seconds`]), the bounds of an
//! Acquire ([`MAX_SAMPLE_RATE`], [`SAMPLE_FORMAT_NAMES`]) and the Acquire options themselves
//! ([`AcquireArgs`], clap; used by `bassd --acquire` and `bass acquire`). The C library does
//! not link this crate.

pub use bassport::format::MAX_SAMPLE_RATE;

/// The sample formats an Acquire may force (ALSA's names), in the broker's order of
/// preference (the broker's converters are checked against this list).
pub const SAMPLE_FORMAT_NAMES: [&str; 5] = ["S32_LE", "S24_LE", "S24_3LE", "FLOAT_LE", "S16_LE"];

/// Longest duration any option accepts, in seconds (about 31.7 years).
pub const MAX_SECONDS: f64 = 1e9;

/// Parses a duration in seconds: a finite number in (0, [`MAX_SECONDS`]]. NaN, infinities,
/// zero and negative values are refused (they used to mean "no limit" or panic).
pub fn parse_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("{s:?} is not a number of seconds"))?;
    if !v.is_finite() || v <= 0.0 || v > MAX_SECONDS {
        return Err(format!(
            "{s} is not in the accepted range: more than 0 and at most {MAX_SECONDS:e} seconds"
        ));
    }
    Ok(v)
}

mod acquire {
    use super::{MAX_SAMPLE_RATE, SAMPLE_FORMAT_NAMES};
    use bassport::control::AcquireRequest;
    use bassport::format::MAX_CHANNELS;

    /// Acquire parameters shared by `bassd --acquire DEVICE` and `bass acquire [DEVICE]`; the
    /// defaults are the seed's ([`AcquireRequest::default`]). Every number is range-checked by
    /// the parser, with a message that names the option and the accepted range.
    #[derive(clap::Args, Clone, Debug, PartialEq, Eq)]
    pub struct AcquireArgs {
        /// Sample rate in Hz
        #[arg(short = 'r', long = "rate", value_name = "HZ",
              default_value_t = AcquireRequest::default().sample_rate,
              value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_SAMPLE_RATE)))]
        pub sample_rate: u32,
        /// Frames per chunk (nFramesPerChunk, the ALSA period)
        #[arg(long = "frames", visible_alias = "period-size", value_name = "N",
              default_value_t = AcquireRequest::default().frames_per_chunk,
              value_parser = clap::value_parser!(u32).range(1..))]
        pub frames_per_chunk: u32,
        /// Chunks on the port (nChunksOnPort): the window holds frames x chunks frames
        #[arg(long = "chunks", value_name = "N",
              default_value_t = AcquireRequest::default().chunks_on_port,
              value_parser = clap::value_parser!(u32).range(1..))]
        pub chunks_on_port: u32,
        /// Channels
        #[arg(short = 'c', long = "channels", value_name = "N",
              default_value_t = AcquireRequest::default().channels,
              value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_CHANNELS)))]
        pub channels: u32,
        /// Device sample format (ALSA devices only; default: the best the device offers)
        #[arg(short = 'f', long = "format", value_name = "FORMAT", value_parser = format_names())]
        pub format: Option<String>,
        /// Replay a sim:file: device in a loop (the same as naming it sim:file-loop:PATH)
        #[arg(long = "loop", conflicts_with = "renumber")]
        pub looping: bool,
        /// Replay a sim:file: device from frame 1 rather than at its recorded frame indices (the
        /// same as naming it sim:file-renumber:PATH)
        #[arg(long)]
        pub renumber: bool,
    }

    impl Default for AcquireArgs {
        fn default() -> Self {
            let d = AcquireRequest::default();
            AcquireArgs {
                sample_rate: d.sample_rate,
                frames_per_chunk: d.frames_per_chunk,
                chunks_on_port: d.chunks_on_port,
                channels: d.channels,
                format: None,
                looping: false,
                renumber: false,
            }
        }
    }

    impl AcquireArgs {
        /// The request for `device`; refuses combinations the broker would silently ignore
        /// (a sample format forced on a simulated device, which always produces S32_LE).
        pub fn request(&self, device: &str) -> Result<AcquireRequest, String> {
            if device.starts_with("sim:") {
                if let Some(f) = &self.format {
                    return Err(format!(
                        "--format {f}: simulated devices always produce S32_LE; --format applies to ALSA devices only"
                    ));
                }
            }
            let device = absolute_replay_path(device)?;
            let device = device.as_str();
            let device = match (self.looping, self.renumber, device.strip_prefix("sim:file:")) {
                (false, false, _) => device.to_owned(),
                (true, _, Some(path)) => format!("sim:file-loop:{path}"),
                (_, true, Some(path)) => format!("sim:file-renumber:{path}"),
                (looping, _, None) => {
                    let opt = if looping { "--loop" } else { "--renumber" };
                    return Err(format!("{opt} applies to sim:file:PATH devices only, not {device:?}"));
                }
            };
            Ok(AcquireRequest {
                device,
                sample_rate: self.sample_rate,
                frames_per_chunk: self.frames_per_chunk,
                chunks_on_port: self.chunks_on_port,
                channels: self.channels,
                format: self.format.clone(),
                followers: Vec::new(),
            })
        }
    }

    /// The file replay devices, whose argument is a path.
    const REPLAY_PREFIXES: [&str; 3] = ["sim:file:", "sim:file-renumber:", "sim:file-loop:"];

    /// `device` with a relative replay path (`sim:file:rec.wav`) made absolute against this
    /// process's working directory: the broker refuses relative paths, since its own working
    /// directory is not the one of the person who typed the name. Other names are unchanged.
    fn absolute_replay_path(device: &str) -> Result<String, String> {
        let Some((prefix, path)) =
            REPLAY_PREFIXES.iter().find_map(|p| device.strip_prefix(p).map(|r| (*p, r)))
        else {
            return Ok(device.to_owned());
        };
        let p = std::path::Path::new(path);
        if path.is_empty() || p.is_absolute() {
            return Ok(device.to_owned());
        }
        let abs = std::path::absolute(p)
            .map_err(|e| format!("{device}: cannot make {path:?} an absolute path: {e}"))?;
        let abs = abs.to_str().ok_or_else(|| format!("{device}: the working directory is not UTF-8"))?;
        Ok(format!("{prefix}{abs}"))
    }

    fn format_names() -> clap::builder::PossibleValuesParser {
        clap::builder::PossibleValuesParser::new(SAMPLE_FORMAT_NAMES)
    }
}
pub use acquire::AcquireArgs;

#[cfg(test)]
mod tests {
    use super::*;
    use bassport::control::AcquireRequest;
    use clap::Parser;

    #[derive(Parser, Debug)]
    struct T {
        #[command(flatten)]
        a: AcquireArgs,
        #[arg(long, value_parser = parse_seconds)]
        seconds: Option<f64>,
    }

    fn parse(args: &str) -> Result<T, String> {
        T::try_parse_from(std::iter::once("t").chain(args.split_whitespace())).map_err(|e| e.to_string())
    }

    #[test]
    fn defaults_are_the_seed_defaults() {
        let t = parse("").unwrap();
        assert_eq!(t.a, AcquireArgs::default());
        assert_eq!(t.a.request("hw:1,0").unwrap(), AcquireRequest::default());
    }

    #[test]
    fn short_options_follow_arecord() {
        let t = parse("-r 48000 -c 4 -f S16_LE --period-size 480 --chunks 7").unwrap();
        assert_eq!(
            (t.a.sample_rate, t.a.channels, t.a.frames_per_chunk, t.a.chunks_on_port),
            (48000, 4, 480, 7)
        );
        assert_eq!(t.a.format.as_deref(), Some("S16_LE"));
    }

    #[test]
    fn out_of_range_numbers_name_the_option_and_the_range() {
        for (args, option, range) in [
            ("--rate 0", "--rate", "1..=768000"),
            ("--rate 768001", "--rate", "1..=768000"),
            ("--channels 65", "--channels", "1..=64"),
            ("--channels 0", "--channels", "1..=64"),
            ("--frames 0", "--frames", "1.."),
            ("--chunks 4294967296", "--chunks", "4294967296"),
        ] {
            let e = parse(args).unwrap_err();
            assert!(e.contains(option) && e.contains(range), "{args}: {e}");
        }
    }

    #[test]
    fn seconds_must_be_finite_positive_and_bounded() {
        for bad in ["inf", "-inf", "NaN", "1e300", "1e19", "-1", "0", "x"] {
            let e = parse(&format!("--seconds={bad}")).unwrap_err();
            assert!(e.contains("--seconds"), "{bad}: {e}");
        }
        assert_eq!(parse("--seconds 0.5").unwrap().seconds, Some(0.5));
        assert_eq!(parse("--seconds 1e9").unwrap().seconds, Some(1e9));
    }

    #[test]
    fn loop_names_the_looping_file_device() {
        let t = parse("--loop").unwrap();
        assert_eq!(t.a.request("sim:file:/r.wav").unwrap().device, "sim:file-loop:/r.wav");
        assert!(t.a.request("sim:sine").unwrap_err().contains("--loop applies to sim:file:"));
        let t = parse("--renumber").unwrap();
        assert_eq!(t.a.request("sim:file:/r.wav").unwrap().device, "sim:file-renumber:/r.wav");
        assert!(t.a.request("hw:0").unwrap_err().contains("--renumber applies to sim:file:"));
    }

    #[test]
    fn a_relative_replay_path_is_made_absolute_against_the_working_directory() {
        let t = parse("").unwrap();
        let cwd = std::env::current_dir().unwrap();
        let cwd = cwd.display();
        assert_eq!(t.a.request("sim:file:rec.wav").unwrap().device, format!("sim:file:{cwd}/rec.wav"));
        assert_eq!(
            t.a.request("sim:file-loop:d/r.wav").unwrap().device,
            format!("sim:file-loop:{cwd}/d/r.wav")
        );
        assert_eq!(t.a.request("sim:file:/abs.wav").unwrap().device, "sim:file:/abs.wav");
        assert_eq!(t.a.request("sim:pattern").unwrap().device, "sim:pattern");
        let t = parse("--loop").unwrap();
        assert_eq!(t.a.request("sim:file:rec").unwrap().device, format!("sim:file-loop:{cwd}/rec"));
    }

    #[test]
    fn a_format_on_a_simulated_device_is_refused() {
        let t = parse("-f S16_LE").unwrap();
        assert!(t.a.request("sim:sine").unwrap_err().contains("ALSA devices only"));
        assert_eq!(t.a.request("hw:0").unwrap().format.as_deref(), Some("S16_LE"));
    }
}
