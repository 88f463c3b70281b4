//! Where the binaries under test are: next to the running test, or named by an environment
//! variable (to run a suite against another build, e.g. to show a test fails on old code).

use std::path::PathBuf;

/// Path of a workspace binary (`bassd`, `bass`, the fault agent): `$env_var` if set, else
/// next to the running test (integration tests live in target/<profile>/deps, binaries one
/// level up). Binaries of another package are built by `cargo build --workspace` first.
pub fn bin_path(name: &str, env_var: &str) -> PathBuf {
    if let Some(p) = std::env::var_os(env_var) {
        return p.into();
    }
    let exe = std::env::current_exe().expect("current exe");
    let dir = exe.parent().expect("exe dir");
    for cand in [dir.join(name), dir.parent().unwrap_or(dir).join(name)] {
        if cand.is_file() {
            return cand;
        }
    }
    panic!("{name} not found next to {} (build the workspace first, or set {env_var})", exe.display())
}

/// The `bassd` under test: `$BASS_BASSD` if set, else the one cargo built.
pub fn bassd_bin() -> String {
    bin_path("bassd", "BASS_BASSD").to_string_lossy().into_owned()
}

/// The `bass` under test: `$BASS_CLI` if set, else the one cargo built.
pub fn bass_bin() -> String {
    bin_path("bass", "BASS_CLI").to_string_lossy().into_owned()
}
