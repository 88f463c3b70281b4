//! The output files: never through a symbolic link, never over a file without `--force`.

use std::fs::{File, OpenOptions};
use std::io;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

use anyhow::Result;

use crate::exit::{self, Exit};

/// Refuses `path` early if it is a symbolic link, or exists without `force` (the race-free
/// refusal is [`create`]'s; this one comes before the broker is asked anything).
pub(super) fn refuse_path(path: &Path, force: bool) -> Result<()> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => Err(symlink_refused(path)),
        Ok(_) if !force => Err(exists_refused(path)),
        _ => Ok(()),
    }
}

pub(super) fn symlink_refused(path: &Path) -> anyhow::Error {
    Exit::new(
        exit::USAGE,
        format!(
            "{} is a symbolic link; bass record does not follow links (not even with --force): give the path of the file itself",
            path.display()
        ),
    )
    .into()
}

pub(super) fn exists_refused(path: &Path) -> anyhow::Error {
    Exit::new(exit::USAGE, format!("{} exists; use --force to overwrite it", path.display())).into()
}

/// Creates `path` for writing: never through a symbolic link (O_NOFOLLOW), never over an
/// existing file unless `force` (O_EXCL).
pub(super) fn create(path: &Path, force: bool) -> Result<File> {
    let mut o = OpenOptions::new();
    o.write(true).custom_flags(libc::O_NOFOLLOW);
    if force {
        o.create(true).truncate(true);
    } else {
        o.create_new(true);
    }
    match o.open(path) {
        Ok(f) => Ok(f),
        Err(e) if e.raw_os_error() == Some(libc::ELOOP) => Err(symlink_refused(path)),
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
            if std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink()) {
                Err(symlink_refused(path))
            } else {
                Err(exists_refused(path))
            }
        }
        Err(e) => Err(anyhow::Error::new(e).context(format!("create {}", path.display()))),
    }
}
