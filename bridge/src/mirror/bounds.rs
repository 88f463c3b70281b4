//! The mirror's own bounds on what a source may ask for: bassd's operator limits
//! ([`basskit::limits::Limits`]: the same options `--max-rate`, `--max-channels`,
//! `--min-chunk-us`, `--max-window-s`, `--max-port-bytes` and the same defaults), checked on
//! every chunk message before anything is allocated. A message outside them is refused whoever
//! sent it: a port the local broker would refuse to make for a local client is not made for a
//! network peer either.

pub use basskit::limits::{Holder, Limits as Bounds};

#[cfg(test)]
mod tests {
    use super::*;
    use bassport::Geometry;

    fn g(channels: u32, sample_rate: u32, frames_per_chunk: u32, chunks_on_port: u32) -> Geometry {
        Geometry { channels, sample_rate, frames_per_chunk, chunks_on_port }
    }

    #[test]
    fn a_usual_source_passes_and_a_huge_geometry_is_refused_before_any_allocation() {
        let b = Bounds::default();
        let check = |geometry| b.check(&geometry, Holder::Mirror);
        assert!(check(g(2, 48_000, 480, 50)).is_ok());
        // The 1 TiB message: 64 channels x 2^20 frames x 4095 chunks, refused by the
        // format's own size limit before any bound is looked at.
        let e = check(g(64, 48_000, 1 << 20, 4095)).unwrap_err();
        assert!(e.contains("exceeds"), "{e}");
        let e = check(g(33, 48_000, 480, 50)).unwrap_err();
        assert!(e.contains("this mirror's limit of 32 (--max-channels)"), "{e}");
        let e = check(g(2, 8_000, 8_000, 3601)).unwrap_err();
        assert!(e.contains("(--max-window-s)"), "{e}");
        let e = check(g(32, 192_000, 19_200, 1000)).unwrap_err();
        assert!(e.contains("(--max-port-bytes)"), "{e}");
        assert!(check(g(2, 768_000, 480, 50)).unwrap_err().contains("(--max-rate)"));
        assert!(check(g(2, 48_000, 16, 50)).unwrap_err().contains("(--min-chunk-us)"));
    }
}
