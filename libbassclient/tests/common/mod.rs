//! Shared test helpers: temporary port paths and the literal model of the seed's port.
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

/// A fresh port path in /dev/shm (real shared memory), unique per process and call.
pub fn temp_port_path(tag: &str) -> PathBuf {
    static N: AtomicU64 = AtomicU64::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let dir =
        if std::path::Path::new("/dev/shm").is_dir() { "/dev/shm".into() } else { std::env::temp_dir() };
    dir.join(format!("bass-test-{tag}-{}-{n}.port", std::process::id()))
}

/// The port of the BASS documentation, literally: arrays of nFOP samples per channel that
/// shift left by one chunk when a chunk arrives, and `lastFrameIndex`.
pub struct SeedPort {
    pub nfpc: usize,
    pub ncop: usize,
    pub channels: Vec<Vec<i32>>,
    pub last_frame_index: i128,
}

/// What the formal `getAudioData` returns.
pub struct SeedRead {
    pub n: i128,
    pub nfr: i128,
    pub loss: i128,
    pub channels: Vec<Vec<i32>>,
}

impl SeedPort {
    pub fn new(nfpc: usize, ncop: usize, channels: usize) -> SeedPort {
        SeedPort { nfpc, ncop, channels: vec![vec![0; nfpc * ncop]; channels], last_frame_index: 0 }
    }

    /// A new chunk: shift every array by nFPC, append the chunk, lastFrameIndex += nFPC.
    pub fn publish_interleaved(&mut self, chunk: &[i32]) {
        let nch = self.channels.len();
        for (c, arr) in self.channels.iter_mut().enumerate() {
            arr.drain(..self.nfpc);
            arr.extend((0..self.nfpc).map(|i| chunk[i * nch + c]));
        }
        self.last_frame_index += self.nfpc as i128;
    }

    /// The formal algorithm, as written in the seed.
    pub fn get_audio_data(&self, big_n: i128, mut nfr: i128) -> SeedRead {
        let nfop = (self.nfpc * self.ncop) as i128;
        let lfi = self.last_frame_index;
        let ofi = std::cmp::max(0, lfi - nfop + 1);
        let mut loss = 0;
        if nfr < ofi {
            loss = ofi - nfr;
            nfr = ofi;
        }
        let mut pos = nfop - (lfi - nfr + 1);
        let mut n = 0;
        let mut out = vec![Vec::new(); self.channels.len()];
        while n < big_n && pos < nfop {
            for (c, arr) in self.channels.iter().enumerate() {
                out[c].push(arr[pos as usize]);
            }
            n += 1;
            pos += 1;
            nfr += 1;
        }
        SeedRead { n, nfr, loss, channels: out }
    }
}
