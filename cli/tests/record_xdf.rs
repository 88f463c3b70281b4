//! `bass record FILE.xdf` against a real bassd on sim:pattern: the extension picks XDF, `--bits`
//! is refused, and a full file system ends the recording naming ENOSPC with a file that PyPI
//! pyxdf reads to the end (every sample the pattern, in order) and `bass record --check`
//! passes; the crate `xdf` 0.1.2 (a reader of its own, in Rust) reads the same samples and
//! stamps as pyxdf. (Samples, stamps and markers against a WAV recorded beside:
//! tests/replay/run.sh.)

use std::path::Path;
use std::process::Command;

use bass_test_support::*;
use basskit::testsignal::pattern_sample;
use serde_json::Value;

/// Reads an XDF recording of sim:pattern with pyxdf and prints one JSON object: the samples,
/// the first frame, whether both streams have footers, the markers, and the samples that are
/// not the pattern of the frame their position and the overrun markers give.
const READ_XDF: &str = r#"
import json, sys
import pyxdf
streams, _ = pyxdf.load_xdf(sys.argv[1], dejitter_timestamps=False)
a = [s for s in streams if s["info"]["type"] == ["Audio"]][0]
m = [s for s in streams if s["info"]["type"] == ["Markers"]][0]
first = int(a["info"]["desc"][0]["bass"][0]["first_frame"][0])
marks = [json.loads(x[0]) for x in m["time_series"]]
lost = {x["first_frame"]: x["frames"] for x in marks if x["cause"] == "overrun"}
def pattern(f, c):
    v = ((f & 0x03FFFFFF) << 6) | (c & 63)
    return v - (1 << 32) if v >= 1 << 31 else v
f, bad = first, []
for s in a["time_series"]:
    f += lost.get(f, 0)
    if [int(v) for v in s] != [pattern(f, c) for c in range(len(s))]:
        bad.append(f)
    f += 1
print(json.dumps({"samples": len(a["time_series"]), "first": first, "frames": f - first,
                  "stamps": [float(t) for t in a["time_stamps"]], "nmarkers": len(marks),
                  "footers": "footer" in a and "footer" in m, "markers": marks, "bad": bad[:5]}))
"#;

fn read_xdf(path: &Path) -> Value {
    let o = Command::new("python3").args(["-c", READ_XDF]).arg(path).output().unwrap();
    assert!(o.status.success(), "pyxdf cannot read {}: {}", path.display(), text(&o));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["bad"], serde_json::json!([]), "{}: {v}", path.display());
    v
}

/// `bass record --check PATH` passes; returns its line.
fn check_ok(path: &Path) -> String {
    let o = Command::new(bass_bin()).args(["record", "--check"]).arg(path).output().unwrap();
    assert_eq!(o.status.code(), Some(0), "bass record --check {}: {}", path.display(), text(&o));
    String::from_utf8_lossy(&o.stdout).trim().to_owned()
}

#[test]
fn a_name_ending_in_xdf_is_an_xdf_file_and_bits_are_refused() {
    // Before the feature `bass record take.xdf` wrote a WAV named take.xdf.
    let dir = TempDir::new("xdf-names");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    let take = dir.join("take.xdf");
    let o = bass(&b, &["record", take.to_str().unwrap(), "--frames", "8000", "-q", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert_eq!(&std::fs::read(&take).unwrap()[..4], b"XDF:");
    assert!(!dir.join("take.xdf.json").exists(), "{:?}", dir.entries());
    let v = read_xdf(&take);
    assert_eq!((v["samples"].as_u64(), v["footers"].as_bool()), (Some(8000), Some(true)), "{v}");
    let line = check_ok(&take);
    assert!(line.contains("8000 frames") && line.contains("with footers"), "{line}");
    same_in_the_xdf_crate(&take, &v);
    let o = bass(&b, &["record", dir.join("b.xdf").to_str().unwrap(), "--bits", "16", "--frames", "80"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains("--format xdf keeps the 32-bit samples") && text(&o).contains("--bits 16"),
        "{}",
        text(&o)
    );
    assert!(!dir.join("b.xdf").exists());
}

/// The crate `xdf` reads in `path` the samples (the pattern from the first frame: no loss)
/// and the stamps (within 1 us) pyxdf read (`v`), and as many markers.
fn same_in_the_xdf_crate(path: &Path, v: &Value) {
    let f = xdf::XDFFile::from_bytes(&std::fs::read(path).unwrap()).expect("the xdf crate reads the file");
    let audio = f.streams.iter().find(|s| s.r#type.as_deref() == Some("Audio")).expect("an Audio stream");
    let markers =
        f.streams.iter().find(|s| s.r#type.as_deref() == Some("Markers")).expect("a Markers stream");
    assert_eq!((audio.channel_count, audio.nominal_srate), (2, Some(8000.0)));
    assert_eq!(markers.samples.len() as u64, v["nmarkers"].as_u64().unwrap());
    let (first, stamps) = (v["first"].as_u64().unwrap(), v["stamps"].as_array().unwrap());
    assert_eq!(audio.samples.len(), stamps.len());
    for (i, s) in audio.samples.iter().enumerate() {
        let want: Vec<i32> = (0..2).map(|c| pattern_sample(first + i as u64, c)).collect();
        assert_eq!(s.values, xdf::Values::Int32(want), "sample {i}");
        let t = s.timestamp.expect("every sample stamped");
        assert!((t - stamps[i].as_f64().unwrap()).abs() <= 1e-6, "sample {i}: {t} vs pyxdf's {}", stamps[i]);
    }
}

#[test]
fn a_full_file_system_ends_an_xdf_recording_naming_enospc_with_a_readable_file() {
    if skip(root_missing()) {
        return; // mounting the small file system needs root
    }
    let dir = TempDir::new("xdf-full");
    let b = Bassd::start_replaying(dir.path(), "default");
    b.client().acquire(&acquire_req("sim:pattern", 8000, 80, 200, 2)).unwrap();
    let fs = Tmpfs::mount(&dir.join("small"), "256k");
    let rec = fs.path().join("full.xdf");
    let o = bass(&b, &["record", rec.to_str().unwrap(), "-q"]);
    let msg = text(&o);
    assert_eq!(o.status.code(), Some(1), "{msg}");
    assert!(msg.contains("No space left on device") && msg.contains(rec.to_str().unwrap()), "{msg}");
    assert!(!msg.contains("sidecar"), "an XDF recording has no sidecar: {msg}");
    let v = read_xdf(&rec);
    let frames = v["frames"].as_u64().unwrap();
    assert!(frames > 8000, "most of the 256 KiB hold frames: {v}");
    assert!(msg.contains(&format!("{frames} frames written")), "the message gives the frames kept: {msg}");
    assert_eq!(v["footers"], true, "the footers of the frames on the disk fit: {v}");
    let line = check_ok(&rec);
    assert!(line.contains(&format!("{frames} frames")), "{line}");
    drop(fs);
}
