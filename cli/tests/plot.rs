//! `bass plot` against a real bassd: a PNG of a recording with its gaps shaded, and of the
//! live port.

use std::path::Path;

use bass_test_support::*;

/// (width, height, RGB pixels) of a PNG.
fn png(path: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::fs::File::open(path).unwrap());
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    (info.width, info.height, buf)
}

#[test]
fn a_recording_is_plotted_with_its_gaps_shaded() {
    let dir = TempDir::new("plot");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:xrun", 8000, 100, 200, 2)).unwrap();
    let wav = dir.path().join("x.wav");
    let o = bass(&b, &["record", wav.to_str().unwrap(), "--from", "1", "--frames", "12000", "-q"]);
    assert!(o.status.success());
    let out = dir.path().join("x.png");
    let o = bass(&b, &["plot", wav.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (w, h, px) = png(&out);
    // Two waveform panels and the RMS panel, 180 pixels each, plus the title.
    assert_eq!((w, h), (1200, 3 * 180 + 40));
    // The plot area spans x = 66..1194 for 0..1.5 s. Frames 4001..4400 (0.5..0.55 s) are a
    // GAP: shaded red at x = 66 + 0.525 / 1.5 * 1128 = 461 in channel 0's panel; not at 0.3 s.
    let at = |x: usize, y: usize| {
        let i = (y * w as usize + x) * 3;
        (u32::from(px[i]), u32::from(px[i + 1]), u32::from(px[i + 2]))
    };
    let (r, g, bl) = at(461, 80);
    assert!(r > 200 && g < 220 && bl < 220 && r > g + 30, "gap pixel {:?}", (r, g, bl));
    let (r, g, bl) = at(292, 80);
    assert!(r <= g + 30, "no gap at 0.3 s: {:?}", (r, g, bl));
    // The port as it is now.
    let live = dir.path().join("live.png");
    let o = bass(&b, &["plot", "--live", "-d", "0.5", "-o", live.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(png(&live).0, 1200);
    // A missing file is an error, not a panic.
    let o = bass(&b, &["plot", "/nonexistent.wav", "-o", live.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
}
