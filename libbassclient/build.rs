//! Gives the shared library its SONAME, `libbassclient.so.0` (the ABI major version: bump it
//! when the C ABI breaks), and makes the build tree look like an installed library: programs
//! linked against `target/<profile>/libbassclient.so` record `libbassclient.so.0`, so a
//! `libbassclient.so.0 -> libbassclient.so` symlink is put beside it. `make install` installs
//! `libbassclient.so.VERSION` with the usual `.so.0` and `.so` symlinks.

use std::path::PathBuf;

/// The SONAME: the C ABI's major version.
const SONAME: &str = "libbassclient.so.0";

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,{SONAME}");
    // OUT_DIR is <target>/<profile>/build/bassclient-<hash>/out: the library lands three
    // levels up. A dangling link until the library is linked is fine.
    let Some(out) = std::env::var_os("OUT_DIR").map(PathBuf::from) else { return };
    let Some(dir) = out.ancestors().nth(3) else { return };
    let link = dir.join(SONAME);
    if std::fs::symlink_metadata(&link).is_err() {
        if let Err(e) = std::os::unix::fs::symlink("libbassclient.so", &link) {
            println!("cargo:warning=cannot create {}: {e}", link.display());
        }
    }
}
