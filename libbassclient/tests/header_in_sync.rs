//! include/bass.h must be exactly what cbindgen generates from the sources now.
//! Regenerate with `BASS_BLESS=1 cargo test -p bassclient --test header_in_sync` (or `make header`).

use std::path::PathBuf;

#[test]
fn committed_header_matches_cbindgen_output() {
    let crate_dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(crate_dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let mut generated = Vec::new();
    cbindgen::Builder::new()
        .with_crate(&crate_dir)
        .with_config(config)
        .generate()
        .expect("cbindgen generates the header")
        .write(&mut generated);
    let path = crate_dir.join("../include/bass.h");
    if std::env::var_os("BASS_BLESS").is_some() {
        std::fs::write(&path, &generated).expect("write include/bass.h");
    }
    let committed = std::fs::read(&path).unwrap_or_default();
    assert!(committed == generated, "include/bass.h is out of date: run `make header` and commit it");
}

/// Every macro and type bass.h defines is in the `BASS_` / `bass_` namespace: a Rust constant
/// that leaks into the header unprefixed (`LATE`, `SLOTS` did) would collide in C users' code.
#[test]
fn the_header_defines_only_prefixed_names() {
    let h = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../include/bass.h")).unwrap();
    let stray: Vec<&str> = h
        .lines()
        .filter_map(|l| l.strip_prefix("#define "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|name| !name.starts_with("BASS_"))
        .collect();
    assert!(stray.is_empty(), "bass.h defines unprefixed names {stray:?}: exclude them in cbindgen.toml");
}
