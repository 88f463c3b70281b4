//! `bass meter` against a real bassd: redrawn in place under a pseudo-terminal (util-linux
//! `script`), one JSON object per update, 1 to 64 channels.

use std::process::{Command, Output};

use bass_test_support::*;
use serde_json::Value;

fn meter(b: &Bassd, args: &[&str]) -> Output {
    Command::new(bass_bin())
        .args(["--name", &b.name, "meter"])
        .args(args)
        .env("BASS_RUNTIME_DIR", &b.dir)
        .output()
        .expect("run bass meter")
}

#[test]
fn the_meter_redraws_in_place_on_a_terminal() {
    let dir = TempDir::new("meter-pty");
    let b = Bassd::start(dir.path(), "default", &[], &[]);
    b.client().acquire(&acquire_req("sim:sine", 8000, 80, 100, 2)).unwrap();
    let cmd = format!("{} --name default meter -n 4 -i 0.1", bass_bin());
    let o = Command::new("script")
        .args(["-qec", &cmd, "/dev/null"])
        .env("BASS_RUNTIME_DIR", dir.path())
        .output()
        .expect("script (util-linux)");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout);
    // Four updates of 3 lines (2 channels + frames); the last three go back up 3 lines first.
    assert_eq!(out.matches("\x1b[3F").count(), 3, "{out:?}");
    let ch0: Vec<&str> = out.split('\n').filter(|l| l.contains("ch0 ")).collect();
    assert_eq!(ch0.len(), 4, "{out:?}");
    // sim:sine is a half-scale sine: peak -6.0 dBFS, RMS -9.0 dBFS.
    for l in ch0 {
        assert!(l.contains("rms   -9.0 peak   -6.0 dBFS"), "{l:?}");
    }
}

#[test]
fn the_meter_prints_one_json_object_per_update_for_1_to_64_channels() {
    let dir = TempDir::new("meter-json");
    // 64 channels are above the broker's default bound (32): the operator widens it.
    let b = Bassd::start(dir.path(), "default", &["--max-channels", "64"], &[]);
    for ch in [1u32, 2, 64] {
        b.client().acquire(&acquire_req("sim:sine", 8000, 80, 100, ch)).unwrap();
        let o = meter(&b, &["--json", "-n", "3", "-i", "0.05"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let ups: Vec<Value> =
            String::from_utf8_lossy(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        assert_eq!(ups.len(), 3);
        for (i, u) in ups.iter().enumerate() {
            assert_eq!(u["rms_dbfs"].as_array().unwrap().len(), ch as usize);
            assert_eq!(u["frames"], 400);
            assert_eq!(u["clip"][0], false);
            if i > 0 {
                let prev = ups[i - 1]["first_frame"].as_u64().unwrap();
                assert_eq!(u["first_frame"].as_u64().unwrap(), prev + 400, "updates follow each other");
            }
        }
        // Plain text when stdout is not a terminal; 64 channels in the compact form.
        let o = meter(&b, &["-n", "1", "-i", "0.05"]);
        let lines = String::from_utf8_lossy(&o.stdout).lines().count();
        assert_eq!(lines, if ch <= 8 { ch as usize + 1 } else { 64 / 4 + 1 }, "{ch} channels");
    }
}
