//! Mapping a port file and viewing it as the typed structures of [`crate::format`].
//!
//! This is the only place that turns raw mapped bytes into references; every view is
//! bounds-checked against the mapping length first.

use std::fs::File;
use std::sync::atomic::AtomicU64;

use memmap2::{MmapOptions, MmapRaw};

use crate::error::{Error, Result};
use crate::format::{ChunkEntry, ChunkExt, Header, Layout, CHUNK_ENTRY_SIZE, CHUNK_EXT_SIZE, HEADER_SIZE};
use crate::sigbus;

/// A shared mapping of a whole port file.
pub struct Mapping {
    /// Declared before `raw`: unregistered before the memory is unmapped.
    guard: Option<sigbus::Guard>,
    raw: MmapRaw,
    len: usize,
    writable: bool,
}

impl Mapping {
    /// Maps `len` bytes of `file` shared; read-only (PROT_READ) unless `writable`.
    pub fn new(file: &File, len: u64, writable: bool) -> Result<Mapping> {
        let len = usize::try_from(len)
            .map_err(|_| Error::Corrupt(format!("file length {len} does not fit in memory")))?;
        if len < HEADER_SIZE {
            return Err(Error::Corrupt(format!(
                "file is {len} bytes, smaller than the {HEADER_SIZE}-byte header"
            )));
        }
        let mut opts = MmapOptions::new();
        opts.len(len);
        let raw = if writable { opts.map_raw(file) } else { opts.map_raw_read_only(file) }
            .map_err(|e| Error::io("mmap of the port file", e))?;
        Ok(Mapping { guard: None, raw, len, writable })
    }

    /// Puts the mapping under the SIGBUS guard ([`sigbus`]): for a port *file*, which its
    /// owner or root can shrink under it. Whether it is guarded (see [`sigbus::Guard::register`]
    /// for when it cannot be).
    pub fn guard(&mut self) -> bool {
        if self.guard.is_none() {
            self.guard = sigbus::Guard::register(self.raw.as_ptr(), self.len, self.writable);
        }
        self.guard.is_some()
    }

    /// Whether the mapping is guarded.
    pub fn guarded(&self) -> bool {
        self.guard.is_some()
    }

    /// Whether the file shrank under a guarded mapping, which the guard then replaced with
    /// zero pages: nothing read from it since is the port's, nothing written reaches anyone.
    pub fn broken(&self) -> bool {
        self.guard.as_ref().is_some_and(sigbus::Guard::broken)
    }

    /// Length of the mapping in bytes.
    pub fn len(&self) -> usize {
        self.len
    }

    /// The header.
    pub fn header(&self) -> &Header {
        // SAFETY: the mapping is at least HEADER_SIZE bytes (checked in `new`), page aligned,
        // and Header consists only of atomics and padding, valid for any bit pattern. The
        // memory stays mapped for the lifetime of `self`. Atomic loads on a PROT_READ
        // mapping are plain loads on the supported targets (x86_64, aarch64).
        unsafe { &*(self.raw.as_ptr() as *const Header) }
    }

    /// The chunk table of a validated layout.
    pub fn chunk_table(&self, layout: &Layout, chunks: u32) -> &[ChunkEntry] {
        let start = layout.chunk_table_offset as usize;
        let count = chunks as usize;
        assert!(
            start % 8 == 0 && start + count * CHUNK_ENTRY_SIZE <= self.len,
            "layout checked against mapping"
        );
        // SAFETY: bounds and alignment asserted above; ChunkEntry is atomics only, valid for
        // any bit pattern; the memory lives as long as `self`.
        unsafe { std::slice::from_raw_parts(self.raw.as_ptr().add(start) as *const ChunkEntry, count) }
    }

    /// The chunk extension table of a validated layout, if the port has one (minor 4).
    pub fn chunk_ext(&self, layout: &Layout, chunks: u32) -> Option<&[ChunkExt]> {
        if layout.ext_table_offset == 0 {
            return None;
        }
        let start = layout.ext_table_offset as usize;
        let count = chunks as usize;
        assert!(
            start % 8 == 0 && start + count * CHUNK_EXT_SIZE <= self.len,
            "layout checked against mapping"
        );
        // SAFETY: bounds and alignment asserted above; ChunkExt is atomics only, valid for any
        // bit pattern; the memory lives as long as `self`.
        Some(unsafe { std::slice::from_raw_parts(self.raw.as_ptr().add(start) as *const ChunkExt, count) })
    }

    /// The sample words of a validated layout (`channels * nFOP` samples, two per word).
    pub fn samples(&self, layout: &Layout, channels: u32) -> &[AtomicU64] {
        let start = layout.samples_offset as usize;
        let count = crate::ring::words_for(layout.frames_on_port * u64::from(channels)) as usize;
        assert!(start % 8 == 0 && start + count * 8 <= self.len, "layout checked against mapping");
        // SAFETY: bounds and alignment asserted above (the mapping is page aligned); AtomicU64
        // is valid for any bit pattern; the memory lives as long as `self`.
        unsafe { std::slice::from_raw_parts(self.raw.as_ptr().add(start) as *const AtomicU64, count) }
    }
}
