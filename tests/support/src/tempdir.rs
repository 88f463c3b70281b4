//! Private temporary directories, removed on drop (tempfile does the naming and cleanup).

use std::path::{Path, PathBuf};

/// A private temporary directory, removed with its contents on drop. Mode 0755 (what the
/// suites had before they shared this rig), so that other uids may look up files in it; tests
/// that need another mode set it themselves.
pub struct TempDir(tempfile::TempDir);

impl TempDir {
    /// A directory `bass-test-<tag>-XXXXXX` in the system temporary directory.
    pub fn new(tag: &str) -> TempDir {
        TempDir::create_in(tag, &std::env::temp_dir())
    }

    /// A directory `bass-test-<tag>-XXXXXX` in /dev/shm (real shared memory: ports created
    /// there are tmpfs pages as in production), or in the system temporary directory on a
    /// machine without /dev/shm.
    pub fn shm(tag: &str) -> TempDir {
        let shm = Path::new("/dev/shm");
        if shm.is_dir() {
            TempDir::create_in(tag, shm)
        } else {
            TempDir::new(tag)
        }
    }

    fn create_in(tag: &str, base: &Path) -> TempDir {
        let dir = tempfile::Builder::new()
            .prefix(&format!("bass-test-{tag}-"))
            .tempdir_in(base)
            .unwrap_or_else(|e| panic!("create a temporary directory in {}: {e}", base.display()));
        let mode = std::os::unix::fs::PermissionsExt::from_mode(0o755);
        std::fs::set_permissions(dir.path(), mode).expect("chmod 0755 the temporary directory");
        TempDir(dir)
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        self.0.path()
    }

    /// A path inside the directory.
    pub fn join(&self, name: &str) -> PathBuf {
        self.0.path().join(name)
    }

    /// Names of the files in the directory, sorted.
    pub fn entries(&self) -> Vec<String> {
        list_dir(self.0.path())
    }
}

/// Names of the files in `dir`, sorted (empty if it cannot be read).
pub fn list_dir(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| rd.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    v.sort();
    v
}
