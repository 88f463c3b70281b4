//! Superseded ports that readers may still pin in shared memory.
//!
//! A port replaced by a new Acquire is unlinked, but its memory lives on for as long as a
//! reader keeps it mapped (or open). Readers are passive, so the broker keeps a descriptor
//! of every port it superseded and asks the kernel whether anybody else still holds it: a
//! write lease (`F_SETLEASE F_WRLCK`) is granted only when no other open file (a mapping
//! holds one) refers to the inode. A port nobody else holds is closed here and its memory
//! returns to the system; the others count as pinned.
//!
//! A memfd port (`--port-backing memfd`) is accounted the same way: bassd hands every reader
//! its own read-only open file description of the memfd (crate::handoff), so the lease sees
//! readers exactly as it sees readers of a port file.
//!
//! The bound this enforces (see docs/reliability.md): an Acquire from a client that is not
//! the broker's own user (nor root) is refused when the pinned superseded ports, the current
//! port and the new one together would exceed [`PIN_BUDGET_FACTOR`] x `--max-port-bytes`.

use std::fs::File;
use std::os::fd::AsFd;

/// Budget of pinned port memory for other users' Acquires, as a multiple of the largest port.
pub const PIN_BUDGET_FACTOR: u64 = 2;

struct Entry {
    file: File,
    bytes: u64,
}

/// The superseded ports the broker still holds a descriptor of.
#[derive(Default)]
pub struct Ledger {
    entries: Vec<Entry>,
    warned: bool,
}

impl Ledger {
    /// Remembers a superseded port (`file` open read-only, `bytes` long).
    pub fn add(&mut self, file: File, bytes: u64) {
        self.entries.push(Entry { file, bytes });
    }

    /// Closes the superseded ports nobody else holds; returns the bytes still pinned by others.
    pub fn prune(&mut self) -> u64 {
        let mut warn = None;
        self.entries.retain(|e| match held_elsewhere(&e.file) {
            Ok(held) => held,
            Err(err) => {
                warn = Some(err);
                false
            }
        });
        if let Some(err) = warn {
            if !std::mem::replace(&mut self.warned, true) {
                tracing::warn!(
                    "cannot tell whether superseded ports are still mapped (F_SETLEASE: {err}); \
                     the bound on memory pinned by readers is not enforced on this file system"
                );
            }
        }
        self.pinned()
    }

    /// Bytes of the superseded ports held (as of the last [`Ledger::prune`]).
    pub fn pinned(&self) -> u64 {
        self.entries.iter().map(|e| e.bytes).sum()
    }

    /// Number of superseded ports held.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no superseded port is held.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// Whether another open file (a reader's descriptor or mapping) refers to `file`'s inode.
fn held_elsewhere(file: &File) -> std::io::Result<bool> {
    crate::os::held_elsewhere(file.as_fd())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_port_is_pinned_while_another_descriptor_or_mapping_holds_it() {
        let dir = std::env::temp_dir().join(format!("bass-pins-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("p");
        std::fs::write(&path, vec![0u8; 8192]).unwrap();
        let reader = File::open(&path).unwrap();
        let map = unsafe_free_map(&reader);
        drop(reader);
        let mut l = Ledger::default();
        l.add(File::open(&path).unwrap(), 8192);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(l.prune(), 8192, "a mapping (descriptor closed) still pins the file");
        drop(map);
        assert_eq!(l.prune(), 0, "nothing pins it after the unmap");
        assert!(l.is_empty());
        let _ = std::fs::remove_dir(&dir);
    }

    #[test]
    fn a_memfd_port_is_pinned_while_a_reader_holds_its_own_descriptor_or_mapping() {
        // As bassd hands a memfd port out: every reader gets its own read-only description
        // (bassport::memfd::reopen_read_only), which the lease sees like a file's reader.
        let port = bassport::memfd::create("pins-test", 8192).unwrap();
        bassport::memfd::seal(&port).unwrap();
        let reader = File::from(bassport::memfd::reopen_read_only(&port).unwrap());
        let map = unsafe_free_map(&reader);
        drop(reader);
        let mut l = Ledger::default();
        l.add(File::from(bassport::memfd::reopen_read_only(&port).unwrap()), 8192);
        drop(port); // the writer is gone (its descriptor and mapping)
        assert_eq!(l.prune(), 8192, "a reader's mapping of the memfd still pins it");
        drop(map);
        assert_eq!(l.prune(), 0, "nothing pins it after the unmap");
    }

    /// A shared read-only mapping through memmap2's safe raw API.
    fn unsafe_free_map(f: &File) -> memmap2::MmapRaw {
        memmap2::MmapOptions::new().len(8192).map_raw_read_only(f).unwrap()
    }
}
