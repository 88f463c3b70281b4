//! What the client library's tests (libbassclient/tests) need without a broker: temporary
//! port paths, child-process entries, waiting for a thread to block, and the literal model of
//! the seed's port.

use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// A fresh port path in /dev/shm (real shared memory), unique per process and call.
pub fn temp_port_path(tag: &str) -> PathBuf {
    static N: AtomicU64 = AtomicU64::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let dir =
        if std::path::Path::new("/dev/shm").is_dir() { "/dev/shm".into() } else { std::env::temp_dir() };
    dir.join(format!("bass-test-{tag}-{}-{n}.port", std::process::id()))
}

/// The text of `rel`, a path from the repository's top (e.g. `include/bass.h`).
pub fn read_repo_file(rel: &str) -> String {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Samples of frames `first..first+frames` in `bufs` (one buffer per channel) that are not
/// the pattern signal's (`basskit::testsignal`); the fault suite's `count_corrupted`.
pub fn count_not_pattern(first: u64, frames: usize, bufs: &[Vec<i32>]) -> u64 {
    let mut wrong = 0;
    for (c, buf) in bufs.iter().enumerate() {
        for (i, &s) in buf[..frames].iter().enumerate() {
            if s != basskit::testsignal::pattern_expected(first + i as u64, c as u32) {
                wrong += 1;
            }
        }
    }
    wrong
}

/// A command that runs test `test` of this test binary as a child process: `--ignored
/// --exact` (child entries are `#[ignore]`d, so a normal run never runs them on their own),
/// with `var` = `value` telling the child its part. See [`child_entry`].
pub fn child_command(test: &str, var: &str, value: impl AsRef<std::ffi::OsStr>) -> Command {
    let mut c = Command::new(std::env::current_exe().expect("the test binary"));
    c.args([test, "--exact", "--ignored", "--nocapture", "--test-threads=1"]).env(var, value);
    c
}

/// The start of a child-process entry (an `#[ignore]`d test run by [`child_command`]): the
/// value of `var`. Panics when the test was run any other way (e.g. `--include-ignored`), so
/// that a child entry can never pass without doing its work.
pub fn child_entry(var: &str) -> String {
    std::env::var(var).unwrap_or_else(|_| {
        panic!("a child-process entry, run by its parent test with {var} set; it does nothing on its own")
    })
}

/// Thread id of the calling thread (for [`wait_blocked_in_futex`]).
pub fn thread_id() -> i32 {
    rustix::thread::gettid().as_raw_nonzero().get()
}

/// Whether thread `tid` of this process is blocked in futex(2) right now (the first field of
/// /proc/self/task/TID/syscall is the number of the system call it sleeps in).
pub fn blocked_in_futex(tid: i32) -> bool {
    std::fs::read_to_string(format!("/proc/self/task/{tid}/syscall"))
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|n| n.parse::<libc::c_long>().ok()))
        == Some(libc::SYS_futex)
}

/// Waits until thread `tid` of this process sleeps in futex(2) (a reader inside `wait`);
/// panics after 20 s, a guard against hanging only.
pub fn wait_blocked_in_futex(tid: i32) {
    let end = Instant::now() + Duration::from_secs(20);
    while !blocked_in_futex(tid) {
        assert!(Instant::now() < end, "thread {tid} never blocked in futex(2)");
        std::thread::sleep(Duration::from_millis(1));
    }
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
