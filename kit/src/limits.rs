//! The operator's bounds on an acquisition: one definition for `bassd` (what a client's
//! Acquire may ask for) and `bass-bridge mirror` (what a source's chunk messages may make it
//! map), with their defaults, their command-line options and the check that names the bound
//! and the option that widens it. The format's own limits ([`MAX_SAMPLE_RATE`],
//! [`MAX_CHANNELS`]) bound the options.
//!
//! The defaults keep the capture thread of one acquisition on the simulated device below 5 %
//! of a core (measured in docs/reliability.md), a window below one hour and a port below
//! 512 MiB (about 23 minutes of 48 kHz stereo); an operator widens them up to the format's
//! limits (768 kHz, 64 channels, 1-frame chunks).

use bassport::format::{Geometry, MAX_CHANNELS, MAX_SAMPLE_RATE};

/// Default largest port (bytes): 512 MiB.
pub const DEFAULT_MAX_PORT_BYTES: u64 = 512 << 20;

/// Operator-set bounds (`--min-chunk-us`, `--max-rate`, `--max-channels`, `--max-window-s`,
/// `--max-port-bytes`, the same options in bassd and the mirror).
#[derive(clap::Args, Clone, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Shortest chunk, in µs (the capture thread wakes once per chunk)
    #[arg(long, value_name = "US", default_value_t = 500,
          value_parser = clap::value_parser!(u32).range(0..=10_000_000))]
    pub min_chunk_us: u32,
    /// Highest sample rate (Hz)
    #[arg(long, value_name = "HZ", default_value_t = 192_000,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_SAMPLE_RATE)))]
    pub max_rate: u32,
    /// Most channels
    #[arg(long, value_name = "N", default_value_t = 32,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_CHANNELS)))]
    pub max_channels: u32,
    /// Longest window (nFramesPerChunk × nChunksOnPort / rate), in seconds
    #[arg(long, value_name = "S", default_value_t = 3600,
          value_parser = clap::value_parser!(u32).range(1..))]
    pub max_window_s: u32,
    /// Largest port file, in bytes
    #[arg(long, value_name = "N", default_value_t = DEFAULT_MAX_PORT_BYTES,
          value_parser = clap::value_parser!(u64).range(1..))]
    pub max_port_bytes: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            min_chunk_us: 500,
            max_rate: 192_000,
            max_channels: 32,
            max_window_s: 3600,
            max_port_bytes: DEFAULT_MAX_PORT_BYTES,
        }
    }
}

/// Whose bounds refuse: the message says "this broker's limit (bassd --max-rate)" or "this
/// mirror's limit (--max-rate)".
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Holder {
    /// `bassd`, refusing a client's Acquire.
    Broker,
    /// `bass-bridge mirror`, refusing a source's chunk message.
    Mirror,
}

impl Holder {
    fn noun(self) -> &'static str {
        match self {
            Holder::Broker => "broker",
            Holder::Mirror => "mirror",
        }
    }

    fn option(self, name: &str) -> String {
        match self {
            Holder::Broker => format!("bassd --{name}"),
            Holder::Mirror => format!("--{name}"),
        }
    }
}

impl Limits {
    /// Refuses a geometry outside the bounds, naming the bound and the option that widens it;
    /// returns the port's size in bytes. Zero sizes and the format's own limits are refused
    /// first (by the format's message), then a port above the memory cap.
    pub fn check(&self, g: &Geometry, who: Holder) -> Result<u64, String> {
        let (this, opt) = (who.noun(), |name| who.option(name));
        let layout =
            g.layout().map_err(|e| e.to_string().trim_start_matches("invalid argument: ").to_owned())?;
        if layout.total_size > self.max_port_bytes {
            return Err(format!(
                "a window of {} x {} frames x {} channels needs a port of {} bytes, above this \
                 {this}'s memory cap of {} bytes ({})",
                g.frames_per_chunk,
                g.chunks_on_port,
                g.channels,
                layout.total_size,
                self.max_port_bytes,
                opt("max-port-bytes")
            ));
        }
        if g.sample_rate > self.max_rate {
            return Err(format!(
                "sampleRate = {} Hz is above this {this}'s limit of {} Hz ({})",
                g.sample_rate,
                self.max_rate,
                opt("max-rate")
            ));
        }
        if g.channels > self.max_channels {
            return Err(format!(
                "channels = {} is above this {this}'s limit of {} ({})",
                g.channels,
                self.max_channels,
                opt("max-channels")
            ));
        }
        let rate = u64::from(g.sample_rate.max(1));
        if u64::from(g.frames_per_chunk) * 1_000_000 < u64::from(self.min_chunk_us) * rate {
            return Err(format!(
                "a chunk of {} frames at {} Hz lasts {:.1} µs, below this {this}'s minimum chunk \
                 duration of {} µs ({})",
                g.frames_per_chunk,
                g.sample_rate,
                f64::from(g.frames_per_chunk) * 1e6 / rate as f64,
                self.min_chunk_us,
                opt("min-chunk-us")
            ));
        }
        let window = u64::from(g.frames_per_chunk) * u64::from(g.chunks_on_port);
        if window > u64::from(self.max_window_s) * rate {
            return Err(format!(
                "a window of {window} frames at {} Hz lasts {:.0} s, above this {this}'s limit of \
                 {} s ({})",
                g.sample_rate,
                window as f64 / rate as f64,
                self.max_window_s,
                opt("max-window-s")
            ));
        }
        Ok(layout.total_size)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn g(channels: u32, sample_rate: u32, frames_per_chunk: u32, chunks_on_port: u32) -> Geometry {
        Geometry { channels, sample_rate, frames_per_chunk, chunks_on_port }
    }

    #[test]
    fn each_bound_is_named_with_the_option_of_its_holder() {
        let l = Limits::default();
        assert!(l.check(&g(2, 48_000, 480, 50), Holder::Broker).is_ok());
        let cases = [
            (g(2, 768_000, 480, 50), "limit of 192000 Hz", "max-rate"),
            (g(33, 48_000, 480, 50), "limit of 32", "max-channels"),
            (g(2, 48_000, 16, 50), "minimum chunk duration of 500 µs", "min-chunk-us"),
            (g(2, 8000, 8000, 3601), "limit of 3600 s", "max-window-s"),
            (g(32, 192_000, 19_200, 1000), "memory cap of 536870912 bytes", "max-port-bytes"),
        ];
        for (geometry, bound, option) in cases {
            let e = l.check(&geometry, Holder::Broker).unwrap_err();
            assert!(
                e.contains(bound)
                    && e.contains("this broker's")
                    && e.ends_with(&format!("(bassd --{option})")),
                "{e}"
            );
            let e = l.check(&geometry, Holder::Mirror).unwrap_err();
            assert!(
                e.contains(bound) && e.contains("this mirror's") && e.ends_with(&format!("(--{option})")),
                "{e}"
            );
        }
        // The format's own refusals come first: zero sizes, more than 64 channels.
        for bad in [
            g(0, 48_000, 480, 50),
            g(2, 0, 480, 50),
            g(2, 48_000, 0, 50),
            g(2, 48_000, 480, 0),
            g(65, 48_000, 480, 50),
        ] {
            assert!(l.check(&bad, Holder::Mirror).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn the_widest_bounds_are_the_formats() {
        let wide = Limits {
            min_chunk_us: 0,
            max_rate: MAX_SAMPLE_RATE,
            max_channels: MAX_CHANNELS,
            ..Limits::default()
        };
        assert!(wide.check(&g(64, 768_000, 1, 4096), Holder::Broker).is_ok());
    }
}
