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

#[test]
fn the_alignment_of_a_several_device_acquisition_is_plotted_and_written_as_csv() {
    let dir = TempDir::new("plot-align");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    let out = dir.path().join("align.png");
    let csv = dir.path().join("align.csv");
    let (o_png, o_csv) = (out.to_str().unwrap(), csv.to_str().unwrap());
    // One device only: nothing to plot, said by name.
    b.client().acquire(&acquire_req("sim:field", 48000, 480, 200, 2)).unwrap();
    let o = bass(&b, &["plot", "--alignment", "-d", "0.5", "-o", o_png]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("no follower device"), "{}", text(&o));
    // Bad options are refused by name with the usage code, before anything is sampled.
    for (args, says) in [
        (&["--alignment", "--interval", "20"][..], "--interval 20 is out of range"),
        (&["--alignment", "--interval", "0.001"][..], "--interval 0.001 is out of range"),
        (&["--alignment", "-d", "5000", "--interval", "0.01"][..], "more than 100000 samples"),
        (&["--alignment", "--live"][..], "--live"),
        (&["--csv", o_csv][..], "--alignment"),
        (&["--alignment", "-d", "soon"][..], "\"soon\" is not a number of seconds"),
    ] {
        let o = bass(&b, &[&["plot"][..], args, &["-o", o_png]].concat());
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o));
        assert!(text(&o).contains(says), "{args:?}: {}", text(&o));
    }
    // Master + a follower at +87 ppm: 3 s of Status every 0.1 s.
    let o = bass(&b, &["acquire", "sim:field", "sim:field?ppm=87&ch=2", "-r", "48000", "--frames", "480"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let o = bass(&b, &["plot", "--alignment", "-d", "3", "--interval", "0.1", "--csv", o_csv, "-o", o_png]);
    assert!(o.status.success(), "{}", text(&o));
    let (w, h, _) = png(&out);
    assert_eq!((w, h), (1200, 3 * 200 + 40), "three panels and the title");
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("t_s,frame,device,name,state,ratio_ppm,error_estimate,locks,xruns,unplugs,missing_frames,unaligned_frames")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    // One row per sample (one follower): at 0, 0.1, ..., 3.0 s (a late sample is not skipped).
    assert_eq!(rows.len(), 31, "{rows:?}");
    let (mut last_t, mut last_frame) = (-1.0f64, 0u64);
    for r in &rows {
        assert_eq!(r.len(), 12, "{r:?}");
        let (t, frame): (f64, u64) = (r[0].parse().unwrap(), r[1].parse().unwrap());
        assert!(t > last_t && frame >= last_frame, "samples in order: {r:?}");
        (last_t, last_frame) = (t, frame);
        assert_eq!((r[2], r[3]), ("1", "sim:field?ppm=87&ch=2"));
        assert!(["waiting", "aligning", "locked"].contains(&r[4]), "{r:?}");
        let (ratio, err): (f64, f64) = (r[5].parse().unwrap(), r[6].parse().unwrap());
        assert!(ratio.is_finite() && err.is_finite() && err >= 0.0, "{r:?}");
    }
    assert!(last_t >= 3.0 - 0.2, "sampled for 3 s: last at {last_t}");
    // The master's frames advanced with time: 3 s at 48 kHz, give or take a chunk and load.
    let first_frame: u64 = rows[0][1].parse().unwrap();
    assert!(last_frame - first_frame >= 48_000 * 2, "{first_frame}..{last_frame}");
    // The rows are Status's counters: never decreasing, and the frames published unaligned
    // grow with the master's frames while the follower is not locked.
    let col = |r: &Vec<&str>, i: usize| r[i].parse::<u64>().unwrap();
    for w in rows.windows(2) {
        for i in [7, 8, 9, 10, 11] {
            assert!(col(&w[1], i) >= col(&w[0], i), "column {i} decreased: {:?} then {:?}", w[0], w[1]);
        }
        if w[1][4] == "aligning" && w[0][4] == "aligning" {
            let (du, df) = (col(&w[1], 11) - col(&w[0], 11), col(&w[1], 1) - col(&w[0], 1));
            assert!(du <= df + 480, "unaligned frames grew by {du} over {df} frames");
        }
    }
    // The ratio column is the follower's measured rate: the simulated card's +87 ppm (within
    // the 5 ppm tests/broker/multi.sh allows) once it has had 2 s of frames.
    let late: Vec<f64> =
        rows.iter().filter(|r| r[0].parse::<f64>().unwrap() > 2.0).map(|r| r[5].parse().unwrap()).collect();
    assert!(!late.is_empty() && late.iter().all(|r| (r - 87.0).abs() < 5.0), "ratios after 2 s: {late:?}");
}
