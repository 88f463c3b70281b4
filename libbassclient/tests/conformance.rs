//! Conformance driver in Rust: replays tests/conformance/vectors.txt (generated from the
//! literal seed model, see tests/conformance/gen_vectors.py) through the writer and reader
//! C ABI and requires the observed `read` results to equal the vectors, bit for bit.
//! With `BASS_CONFORMANCE_OUT=FILE` it also writes the replayed file there, for the
//! cross-language comparison in tests/conformance/run.sh.

use std::ffi::{CStr, CString};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::ptr;

use bassclient::*;

fn check(call: &str, r: bass_result) {
    if r != bass_result::BASS_OK {
        // SAFETY: bass_last_error returns a valid NUL-terminated string.
        let detail = unsafe { CStr::from_ptr(bass_last_error()) }.to_string_lossy().into_owned();
        panic!("{call}: {r:?} ({detail})");
    }
}

/// Replays the vectors; returns the text a conforming driver prints.
fn replay(vectors: &str, port_name: &str) -> String {
    let name = CString::new(port_name).unwrap();
    let device = CString::new("conformance").unwrap();
    let mut writer: *mut bass_writer = ptr::null_mut();
    let mut port: *mut bass_port = ptr::null_mut();
    let mut out = String::new();
    let mut channels = 0usize;
    for line in vectors.lines() {
        let tok: Vec<&str> = line.split_whitespace().collect();
        let Some(&op) = tok.first() else { continue };
        match op {
            "case" => {
                let g: Vec<u32> = tok[2..6].iter().map(|t| t.parse().unwrap()).collect();
                channels = g[0] as usize;
                // SAFETY: valid C strings and out pointers.
                check("bass_writer_create", unsafe {
                    bass_writer_create(name.as_ptr(), device.as_ptr(), g[1], g[2], g[3], g[0], &mut writer)
                });
                // SAFETY: valid C string and out pointer.
                check("bass_port_open", unsafe { bass_port_open(name.as_ptr(), &mut port) });
                writeln!(out, "case {} {} {} {} {}", tok[1], g[0], g[1], g[2], g[3]).unwrap();
            }
            "publish" => {
                let s: Vec<i32> = tok[1..].iter().map(|t| t.parse().unwrap()).collect();
                // SAFETY: `s` holds s.len() samples; NULL meta and out pointer are allowed.
                check("bass_writer_publish_interleaved", unsafe {
                    bass_writer_publish_interleaved(writer, s.as_ptr(), s.len(), ptr::null(), ptr::null_mut())
                });
                let text: Vec<String> = s.iter().map(|v| v.to_string()).collect();
                writeln!(out, "publish {}", text.join(" ")).unwrap();
            }
            "read" => {
                let n_frames: usize = tok[1].parse().unwrap();
                let nfr_in: u64 = tok[2].parse().unwrap();
                let (mut left, mut right) = (vec![0i32; n_frames.max(1)], vec![0i32; n_frames.max(1)]);
                let (mut nfr, mut n, mut loss) = (nfr_in, 0usize, 0u64);
                // SAFETY: both buffers hold at least n_frames samples; out pointers are valid.
                check("bass_get_audio_data", unsafe {
                    bass_get_audio_data(
                        port,
                        n_frames,
                        &mut nfr,
                        left.as_mut_ptr(),
                        right.as_mut_ptr(),
                        &mut n,
                        &mut loss,
                    )
                });
                write!(out, "read {n_frames} {nfr_in} {n} {nfr} {loss}").unwrap();
                for i in 0..n {
                    write!(out, " {} {}", left[i], right[i]).unwrap();
                }
                out.push('\n');
            }
            "readm" => {
                let n_frames: usize = tok[1].parse().unwrap();
                let nfr_in: u64 = tok[2].parse().unwrap();
                let mut bufs = vec![vec![0i32; n_frames.max(1)]; channels];
                let ptrs: Vec<*mut i32> = bufs.iter_mut().map(|b| b.as_mut_ptr()).collect();
                let (mut nfr, mut n, mut loss) = (nfr_in, 0usize, 0u64);
                // SAFETY: `channels` buffers of at least n_frames samples each, not overlapping.
                check("bass_get_audio_data_multi", unsafe {
                    bass_get_audio_data_multi(
                        port,
                        n_frames,
                        &mut nfr,
                        ptrs.as_ptr(),
                        channels,
                        &mut n,
                        &mut loss,
                    )
                });
                write!(out, "readm {n_frames} {nfr_in} {n} {nfr} {loss}").unwrap();
                for i in 0..n {
                    for b in &bufs {
                        write!(out, " {}", b[i]).unwrap();
                    }
                }
                out.push('\n');
            }
            "end" => {
                // SAFETY: handles returned by the library, closed once.
                unsafe {
                    check("bass_port_close", bass_port_close(port));
                    check("bass_writer_close", bass_writer_close(writer));
                }
                out.push_str("end\n");
            }
            _ => {
                out.push_str(&tok.join(" "));
                out.push('\n');
            }
        }
    }
    out
}

#[test]
fn replaying_the_seed_model_vectors_through_the_c_abi_gives_the_model_results() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let vectors = std::fs::read_to_string(root.join("tests/conformance/vectors.txt")).expect("vectors.txt");
    let dir = std::env::temp_dir().join(format!("bass-conformance-rs-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::env::set_var("BASS_RUNTIME_DIR", &dir);
    let out = replay(&vectors, "conf-rust");
    std::fs::remove_dir_all(&dir).unwrap();
    if let Some(path) = std::env::var_os("BASS_CONFORMANCE_OUT") {
        std::fs::write(path, &out).expect("write BASS_CONFORMANCE_OUT");
    }
    for (i, (want, got)) in vectors.lines().zip(out.lines()).enumerate() {
        assert_eq!(got, want, "vectors.txt line {} differs", i + 1);
    }
    assert_eq!(out.lines().count(), vectors.lines().count());
    assert!(
        vectors.lines().filter(|l| l.starts_with("read ")).count() > 100,
        "the vectors hold the read requests"
    );
}
