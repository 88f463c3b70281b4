//! A real, small tmpfs (needs root): a port directory that runs out of space for real.

use std::path::{Path, PathBuf};
use std::process::Command;

/// A tmpfs mounted at a directory (created if missing), unmounted (lazily, so a process
/// still holding a file there cannot keep it) and the directory removed on drop.
pub struct Tmpfs(PathBuf);

impl Tmpfs {
    /// Mounts a tmpfs of `size` (`mount -o size=`, e.g. "2m") and mode 0700 at `dir`;
    /// panics naming the directory if it cannot (not root).
    pub fn mount(dir: &Path, size: &str) -> Tmpfs {
        std::fs::create_dir_all(dir).expect("create the mount point");
        let st = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size},mode=0700"), "bass-test-tmpfs"])
            .arg(dir)
            .status()
            .expect("run mount");
        assert!(st.success(), "mount -t tmpfs on {} failed (needs root)", dir.display());
        Tmpfs(dir.to_owned())
    }

    /// The mount point.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
        let _ = std::fs::remove_dir(&self.0);
    }
}
