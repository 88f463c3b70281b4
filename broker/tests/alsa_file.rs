//! Real ALSA, no sound card: the `file` PCM plugin (over `null`) with an `infile`, for every
//! sample format bass accepts — exact samples from the file through bassd and the port.
//!
//! The file plugin is not paced: it delivers as fast as it is read. To keep the frames on the
//! port until the test has read them, the infile is a FIFO holding exactly the test data: the
//! broker captures those frames, then blocks reading the FIFO (and its stall watchdog ends
//! the acquisition), so nothing overwrites them.

use std::io::Write;
use std::os::fd::AsRawFd;
use std::path::Path;

use bass_test_support::*;
use basskit::testsignal::pattern_sample;

const NFPC: u32 = 441;
const CHUNKS: u64 = 10;
const FRAMES: u64 = NFPC as u64 * CHUNKS;

/// A test value with all bits in play (sign included) for frame `f`, channel `c`.
fn value(f: u64, c: u32) -> i32 {
    pattern_sample(f, c).wrapping_mul(0x9E37_79B1_u32 as i32)
}

/// The raw little-endian sample of `v` in `format`, and what the port must hold for it.
fn encode(format: &str, v: i32, out: &mut Vec<u8>) -> i32 {
    match format {
        "S16_LE" => {
            let s = v as i16;
            out.extend_from_slice(&s.to_le_bytes());
            i32::from(s) << 16
        }
        "S24_LE" => {
            // 24 bits in the low bytes; a garbage top byte must be ignored.
            let raw = (v as u32 & 0x00FF_FFFF) | 0xA5 << 24;
            out.extend_from_slice(&raw.to_le_bytes());
            ((v as u32) << 8) as i32
        }
        "S24_3LE" => {
            out.extend_from_slice(&v.to_le_bytes()[..3]);
            ((v as u32) << 8) as i32
        }
        "S32_LE" => {
            out.extend_from_slice(&v.to_le_bytes());
            v
        }
        "FLOAT_LE" => {
            let k = v >> 16;
            out.extend_from_slice(&(k as f32 / 32768.0).to_le_bytes());
            k << 16
        }
        other => panic!("format {other}"),
    }
}

fn mkfifo(path: &Path) {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

/// Captures the test data in `format` (forced, or the broker's choice if None) and checks
/// every sample.
fn capture_through_file_plugin(format: Option<&str>, expect_format: &str) {
    let dir = TempDir::new(&format!("file-{expect_format}"));
    let fifo = dir.path().join("in.fifo");
    mkfifo(&fifo);
    let rc = dir.path().join("asoundrc");
    std::fs::write(
        &rc,
        format!(
            "pcm.bass_file {{\n  type file\n  slave.pcm \"null\"\n  file \"/dev/null\"\n  infile \"{}\"\n  format \"raw\"\n}}\n",
            fifo.display()
        ),
    )
    .unwrap();
    let alsa_path = format!("/usr/share/alsa/alsa.conf:{}", rc.display());
    // The rig's own PCM is an inline-configured file plugin: the operator allows it by name.
    let b = Bassd::start(
        dir.path(),
        "default",
        &["--allow-device", "bass_file"],
        &[("ALSA_CONFIG_PATH", &alsa_path)],
    );

    // The FIFO holds exactly FRAMES frames (O_RDWR: opening does not wait for a reader).
    let mut w = std::fs::OpenOptions::new().read(true).write(true).open(&fifo).unwrap();
    // SAFETY: fcntl on an open pipe; a bigger pipe holds the whole test data.
    unsafe { libc::fcntl(w.as_raw_fd(), libc::F_SETPIPE_SZ, 1 << 20) };
    let mut raw = Vec::new();
    let mut expected = [Vec::new(), Vec::new()];
    for f in 1..=FRAMES {
        for c in 0..2u32 {
            expected[c as usize].push(encode(expect_format, value(f, c), &mut raw));
        }
    }
    assert!(raw.len() <= 1 << 20);
    w.write_all(&raw).unwrap();

    let mut r = acquire_req("bass_file", 48000, NFPC, 20, 2);
    r.format = format.map(str::to_owned);
    let a = b.client().acquire(&r).unwrap();
    assert_eq!(a.format, expect_format);
    let port = b.port();
    wait_frame(&port, FRAMES);
    let got = read_frames(&port, 1, FRAMES);
    for c in 0..2 {
        for (i, (g, e)) in got[c].iter().zip(&expected[c]).enumerate() {
            assert_eq!(
                g,
                e,
                "{expect_format}: frame {} channel {c}: got {g:#010x}, expected {e:#010x}",
                i + 1
            );
        }
    }
    assert_eq!(b.client().status().unwrap().format, expect_format);
    // Let the plugin see the end of its infile, then stop.
    drop(w);
    b.client().stop().unwrap();
}

#[test]
fn file_plugin_s16_le_samples_arrive_exactly() {
    capture_through_file_plugin(Some("S16_LE"), "S16_LE");
}

#[test]
fn file_plugin_s24_le_samples_arrive_exactly() {
    capture_through_file_plugin(Some("S24_LE"), "S24_LE");
}

#[test]
fn file_plugin_s24_3le_samples_arrive_exactly() {
    capture_through_file_plugin(Some("S24_3LE"), "S24_3LE");
}

#[test]
fn file_plugin_s32_le_samples_arrive_exactly() {
    capture_through_file_plugin(Some("S32_LE"), "S32_LE");
}

#[test]
fn file_plugin_float_le_samples_arrive_exactly() {
    capture_through_file_plugin(Some("FLOAT_LE"), "FLOAT_LE");
}

#[test]
fn the_broker_prefers_s32_when_the_device_offers_every_format() {
    capture_through_file_plugin(None, "S32_LE");
}

/// ALSA plugin strings from a control client are refused by the device
/// policy before `snd_pcm_open` sees them: the `file` plugin's pipe (`|cmd`, a command run as
/// the broker's user) and its output file are never touched; an operator's
/// `--allow-device` pattern is what lets a PCM that ListDevices does not show through.
/// (Before the policy, the pipe ran `touch` and the refusal came from ALSA, if at all.)
#[test]
fn plugin_strings_from_clients_are_refused_and_run_or_write_nothing() {
    let dir = TempDir::new("policy");
    let infile = dir.path().join("in.raw");
    std::fs::write(&infile, vec![0u8; 441 * 8 * 40]).unwrap();
    let rc = dir.path().join("asoundrc");
    std::fs::write(
        &rc,
        format!(
            "pcm.bass_hidden {{\n  type file\n  slave.pcm \"null\"\n  file \"/dev/null\"\n  infile \"{}\"\n  format \"raw\"\n  hint.show off\n}}\n",
            infile.display()
        ),
    )
    .unwrap();
    let alsa_path = format!("/usr/share/alsa/alsa.conf:{}", rc.display());
    let env = [("ALSA_CONFIG_PATH", alsa_path.as_str())];
    let b = Bassd::start(dir.path(), "default", &[], &env);
    let mut c = b.client();
    let pwned = dir.path().join("pwned");
    let written = dir.path().join("x.raw");
    let attacks = [
        (format!("file:'|touch {}',raw", pwned.display()), "pipe"),
        (format!("file:'{}',raw", written.display()), "names a file"),
        (format!("tee:null,'{}',raw", written.display()), "names a file"),
        ("plug:{ type null }".to_owned(), "inline plugin"),
        // Configured but not listed in ListDevices (hint.show off): only a pattern lets it in.
        ("bass_hidden".to_owned(), "not a card reference"),
    ];
    for (dev, why) in &attacks {
        let e = c.acquire(&acquire_req(dev, 44100, 441, 10, 2)).expect_err(dev).to_string();
        assert!(e.contains("device policy") && e.contains(why) && e.contains("[permission]"), "{dev}: {e}");
    }
    assert!(!pwned.exists(), "the pipe command ran");
    assert!(!written.exists(), "the output file was created");
    assert_eq!(c.status().unwrap().epoch, 0, "a refused Acquire touched the port");
    drop(c);
    drop(b);

    // Widened by the operator: the configured PCM opens and captures.
    let b = Bassd::start(dir.path(), "wide", &["--allow-device", "bass_*"], &env);
    let a = b.client().acquire(&acquire_req("bass_hidden", 44100, 441, 10, 2)).unwrap();
    assert_eq!(a.epoch, 1);
    wait_frame(&b.port(), 441);
    assert!(!pwned.exists() && !written.exists());
}
