//! The mirror's own bounds on what a source may ask for: the same operator limits as bassd's
//! (`--max-rate`, `--max-channels`, `--min-chunk-us`, `--max-window-s`, `--max-port-bytes`,
//! with bassd's defaults), checked on every chunk message before anything is allocated. A
//! message outside them is refused whoever sent it: a port the local broker would refuse to
//! make for a local client is not made for a network peer either.

use bassport::Geometry;

/// Operator bounds of the replica port (mirror command line).
#[derive(clap::Args, Clone, Debug, PartialEq, Eq)]
pub struct Bounds {
    /// Highest sample rate a source may have (Hz), as bassd --max-rate.
    #[arg(long, default_value_t = 192_000, value_parser = clap::value_parser!(u32).range(1..=768_000))]
    pub max_rate: u32,
    /// Most channels, as bassd --max-channels.
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub max_channels: u32,
    /// Shortest chunk (µs), as bassd --min-chunk-us.
    #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u32).range(0..=10_000_000))]
    pub min_chunk_us: u32,
    /// Longest window (nFramesPerChunk × nChunksOnPort / rate, seconds), as bassd --max-window-s.
    #[arg(long, default_value_t = 3600, value_parser = clap::value_parser!(u32).range(1..=86_400))]
    pub max_window_s: u32,
    /// Largest replica port (bytes), as bassd --max-port-bytes.
    #[arg(long, default_value_t = 512 << 20, value_parser = clap::value_parser!(u64).range(4096..))]
    pub max_port_bytes: u64,
}

impl Default for Bounds {
    fn default() -> Self {
        Bounds {
            max_rate: 192_000,
            max_channels: 32,
            min_chunk_us: 500,
            max_window_s: 3600,
            max_port_bytes: 512 << 20,
        }
    }
}

impl Bounds {
    /// Checks a source geometry; returns the replica port's size in bytes, or why it is refused
    /// (naming the bound and the option that widens it).
    pub fn check(&self, g: &Geometry) -> Result<u64, String> {
        if g.sample_rate == 0 || g.sample_rate > self.max_rate {
            return Err(format!(
                "sample rate {} Hz is outside this mirror's limit of 1..={} Hz (--max-rate)",
                g.sample_rate, self.max_rate
            ));
        }
        if g.channels == 0 || g.channels > self.max_channels {
            return Err(format!(
                "{} channels is outside this mirror's limit of 1..={} (--max-channels)",
                g.channels, self.max_channels
            ));
        }
        let rate = u64::from(g.sample_rate);
        if g.frames_per_chunk == 0
            || u64::from(g.frames_per_chunk) * 1_000_000 < u64::from(self.min_chunk_us) * rate
        {
            return Err(format!(
                "a chunk of {} frames at {} Hz is shorter than this mirror's minimum of {} µs (--min-chunk-us)",
                g.frames_per_chunk, g.sample_rate, self.min_chunk_us
            ));
        }
        let window = u64::from(g.frames_per_chunk) * u64::from(g.chunks_on_port);
        if g.chunks_on_port == 0 || window > u64::from(self.max_window_s) * rate {
            return Err(format!(
                "a window of {} x {} frames at {} Hz is longer than this mirror's limit of {} s (--max-window-s)",
                g.frames_per_chunk, g.chunks_on_port, g.sample_rate, self.max_window_s
            ));
        }
        let size = g.layout().map_err(|e| format!("geometry refused by the port format: {e}"))?.total_size;
        if size > self.max_port_bytes {
            return Err(format!(
                "the replica port would take {} bytes, above this mirror's limit of {} (--max-port-bytes)",
                size, self.max_port_bytes
            ));
        }
        Ok(size)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn g(channels: u32, sample_rate: u32, frames_per_chunk: u32, chunks_on_port: u32) -> Geometry {
        Geometry { channels, sample_rate, frames_per_chunk, chunks_on_port }
    }

    #[test]
    fn a_usual_source_passes_and_a_huge_geometry_is_refused_before_any_allocation() {
        let b = Bounds::default();
        assert!(b.check(&g(2, 48_000, 480, 50)).is_ok());
        // The 1 TiB message: 64 channels x 2^20 frames x 4095 chunks.
        let e = b.check(&g(64, 48_000, 1 << 20, 4095)).unwrap_err();
        assert!(e.contains("--max-channels"), "{e}");
        let e = b.check(&g(32, 192_000, 1 << 20, 4095)).unwrap_err();
        assert!(e.contains("--max-window-s"), "{e}");
        let e = b.check(&g(32, 192_000, 19_200, 1000)).unwrap_err();
        assert!(e.contains("--max-port-bytes"), "{e}");
        assert!(b.check(&g(2, 768_000, 480, 50)).unwrap_err().contains("--max-rate"));
        assert!(b.check(&g(2, 48_000, 16, 50)).unwrap_err().contains("--min-chunk-us"));
    }

    #[test]
    fn the_defaults_are_bassds() {
        // One definition in spirit: these are the numbers of bassd's `Limits::default()` and
        // DEFAULT_MAX_PORT_BYTES (broker/src/request.rs, server.rs), asserted there too.
        let l = bassd::request::Limits::default();
        let b = Bounds::default();
        assert_eq!(
            (b.max_rate, b.max_channels, b.min_chunk_us, b.max_window_s, b.max_port_bytes),
            (
                l.max_rate,
                l.max_channels,
                l.min_chunk_us,
                l.max_window_s,
                bassd::server::DEFAULT_MAX_PORT_BYTES
            )
        );
    }
}
