//! Unit tests of the file replay: shape refusals, sample conversion, FIFOs.

use super::*;

#[test]
fn a_rate_or_channel_mismatch_is_refused_with_the_files_values() {
    let dir = std::env::temp_dir().join(format!("bass-file-dev-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("a.wav");
    let spec = hound::WavSpec {
        channels: 2,
        sample_rate: 8000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(&p, spec).unwrap();
    for i in 0..200 {
        w.write_sample(i as i16).unwrap();
    }
    w.finalize().unwrap();
    let e = open(&p, Mode::Recorded, 48000, 2, 80).err().unwrap();
    assert!(e.contains("8000 Hz, 2 channel(s)") && e.contains("--rate 8000 --channels 2"), "{e}");
    assert!(open(&p, Mode::Recorded, 8000, 1, 80).err().unwrap().contains("--channels 2"));
    let mut d = open(&p, Mode::Recorded, 8000, 2, 80).unwrap();
    let mut out = vec![0; 20];
    d.fill(0, &mut out, 10).unwrap();
    assert_eq!(out[3], 3 << 16, "16-bit samples are left-justified");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_fifo_is_refused_at_once_without_blocking_in_open() {
    let dir = std::env::temp_dir().join(format!("bass-file-fifo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("fifo.wav");
    rustix::fs::mknodat(
        rustix::fs::CWD,
        &p,
        rustix::fs::FileType::Fifo,
        rustix::fs::Mode::RUSR | rustix::fs::Mode::WUSR,
        0,
    )
    .unwrap();
    // With a blocking open this call never returns (nobody writes to the FIFO).
    let e = open(&p, Mode::Recorded, 48000, 2, 480).err().expect("a FIFO is refused");
    assert!(e.contains("is a FIFO: give a regular WAV file"), "{e}");
    let e = open(Path::new("/dev/null"), Mode::Recorded, 48000, 2, 480).err().expect("/dev/null is refused");
    assert!(e.contains("is a device node"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}
