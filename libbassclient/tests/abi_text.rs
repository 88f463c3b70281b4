//! The text-returning exports (`bass_result_str`, `bass_version`, `bass_last_error`):
//! `bass_result_str` covers exactly the header's result codes through a checked conversion,
//! and `bass_last_error` can be called from a thread-local destructor (thread teardown)
//! without a panic reaching the C ABI.

use bass_test_support::client as common;

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::ffi::{c_int, CStr};

use bassclient::{
    bass_last_error, bass_port_open, bass_result, bass_result_name, bass_result_str, bass_state_str,
    bass_version,
};

fn text(p: *const std::ffi::c_char) -> String {
    assert!(!p.is_null(), "a text export returned NULL");
    // SAFETY: the exports return static (or thread-local) NUL-terminated strings.
    unsafe { CStr::from_ptr(p) }.to_str().expect("UTF-8").to_string()
}

fn header() -> String {
    common::read_repo_file("include/bass.h")
}

#[test]
fn the_code_list_is_the_headers_enum_and_every_code_has_its_own_text() {
    for (i, &r) in bass_result::all().iter().enumerate() {
        assert_eq!(r as usize, i, "codes in numbering order");
        let name = text(bass_result_name(r as c_int));
        assert_eq!(name, format!("{r:?}"), "bass_result_name of {r:?}");
        assert!(header().contains(&format!("  {name} = {i},")), "{name} = {i} is not in bass.h");
    }
    assert_eq!(text(bass_result_name(-1)), "BASS_UNKNOWN");
    assert_eq!(text(bass_result_name(bass_result::all().len() as c_int)), "BASS_UNKNOWN");
    let unknown = text(bass_result_str(-1));
    assert_eq!(unknown, "unknown result code");
    let mut seen = BTreeMap::new();
    for &r in bass_result::all() {
        assert_eq!(bass_result::from_code(r as c_int), Some(r));
        let t = text(bass_result_str(r as c_int));
        assert_ne!(t, unknown, "{r:?} has no text");
        assert!(seen.insert(t.clone(), r).is_none(), "{r:?} shares its text {t:?}");
    }
    let past = bass_result::all().len() as c_int;
    for code in [past, past + 1, -1, c_int::MIN, c_int::MAX] {
        assert_eq!(bass_result::from_code(code), None, "{code}");
        assert_eq!(text(bass_result_str(code)), unknown, "{code}");
    }
}

#[test]
fn every_header_state_has_its_name_and_other_values_are_unknown() {
    let header = header();
    let states: Vec<(String, u32)> = header
        .lines()
        .filter_map(|l| l.strip_prefix("#define BASS_STATE_"))
        .map(|l| {
            let (name, value) = l.split_once(' ').expect("#define NAME value");
            (name.to_ascii_lowercase(), value.trim().parse().expect("numeric state"))
        })
        .collect();
    assert!(states.len() >= 6, "{states:?}");
    for (name, value) in &states {
        assert_eq!(&text(bass_state_str(*value)), name, "BASS_STATE_{}", name.to_uppercase());
    }
    let past = states.iter().map(|(_, v)| v).max().expect("states") + 1;
    for v in [past, past + 1, u32::MAX] {
        assert_eq!(text(bass_state_str(v)), "unknown", "{v}");
    }
}

/// Calls the exports from its destructor, which runs during thread teardown, possibly after
/// the library's own thread-local is gone.
struct CallsAtTeardown(RefCell<Vec<String>>);

impl Drop for CallsAtTeardown {
    fn drop(&mut self) {
        // A failing call (sets the last error) and the three text exports.
        // SAFETY: a NULL name is refused before anything is read; the out pointer is valid.
        let code = unsafe { bass_port_open(std::ptr::null(), &mut std::ptr::null_mut()) };
        let mut out = self.0.borrow_mut();
        out.push(format!("{code:?}"));
        out.push(text(bass_last_error()));
        out.push(text(bass_result_str(code as c_int)));
        out.push(text(bass_version()));
        eprintln!("teardown calls: {out:?}");
    }
}

thread_local! {
    static TEARDOWN: CallsAtTeardown = const { CallsAtTeardown(RefCell::new(Vec::new())) };
}

/// The child process of `text_exports_survive_thread_teardown` (fails if run on its own).
#[test]
#[ignore = "child process of text_exports_survive_thread_teardown, which runs it"]
fn teardown_child() {
    common::child_entry("BASS_TEARDOWN_CHILD");
    std::thread::spawn(|| {
        // Registered first, so destroyed after the library's thread-local, which the
        // failing call below creates.
        TEARDOWN.with(|t| t.0.borrow_mut().clear());
        // SAFETY: a NULL name is refused before anything is read; the out pointer is valid.
        let code = unsafe { bass_port_open(std::ptr::null(), &mut std::ptr::null_mut()) };
        assert_eq!(code, bass_result::BASS_ERR_NULL_ARGUMENT);
        assert!(text(bass_last_error()).contains("argument name is NULL"));
    })
    .join()
    .expect("thread");
    println!("teardown child done");
}

#[test]
fn text_exports_survive_thread_teardown() {
    // A panic in an `extern "C"` function aborts the process, so the calls run in a child.
    let out =
        common::child_command("teardown_child", "BASS_TEARDOWN_CHILD", "1").output().expect("run the child");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "child failed: {:?}\n{stdout}\n{stderr}", out.status);
    assert!(stdout.contains("teardown child done"), "{stdout}\n{stderr}");
    assert!(stderr.contains("teardown calls: [\"BASS_ERR_NULL_ARGUMENT\""), "{stderr}");
}
