//! The raw-futex baselines of part 3: a ping-pong pair (the floor of one wake) and a bare
//! FUTEX_WAIT broadcast (the floor of many), and the child that waits on a port's futex word
//! without the library.

use std::sync::atomic::Ordering::{Acquire, Relaxed, Release};
use std::time::Duration;

use bassport::sys::{futex_wait, futex_wake_all, monotonic_ns};
use bassport::{Port, State};

use crate::procs::{finish_all, spawn_ready, Child};
use crate::shm::Region;

use super::{samples_of, Samples, WAKE_NFPC};

const PING: usize = 0;
const PING_T: usize = 8;
const PONG: usize = 16;
const STOP: usize = 20;

/// The parent side of the raw futex ping-pong.
pub(super) struct Pinger {
    region: Region,
    kid: Child,
    path: std::path::PathBuf,
}

impl Pinger {
    pub(super) fn start() -> Pinger {
        let path = bassport::paths::runtime_dir().join("bench-futex");
        let region = Region::create(&path, 4096);
        let mut kid = Child::spawn("futex-pong", &[path.display().to_string()]);
        kid.ready();
        Pinger { region, kid, path }
    }

    /// One ping; returns when the child has answered (and is about to block again).
    pub(super) fn ping(&self) {
        let r = &self.region;
        let pong = r.u32_at(PONG).load(Acquire);
        r.u64_at(PING_T).store(monotonic_ns(), Relaxed);
        r.u32_at(PING).fetch_add(1, Release);
        futex_wake_all(r.u32_at(PING));
        while r.u32_at(PONG).load(Acquire) == pong {
            futex_wait(r.u32_at(PONG), pong, Duration::from_secs(1));
        }
    }

    /// Stops the child; returns its latencies (ns).
    pub(super) fn finish(self) -> Vec<f64> {
        let r = &self.region;
        r.u32_at(STOP).store(1, Release);
        r.u32_at(PING).fetch_add(1, Release);
        futex_wake_all(r.u32_at(PING));
        let lines = self.kid.finish();
        let _ = std::fs::remove_file(&self.path);
        lines.iter().filter_map(|l| l.strip_prefix("lat ")).filter_map(|v| v.parse().ok()).collect()
    }
}

/// Child: the other side of the raw futex ping-pong.
pub fn child_futex_pong(args: &[String]) {
    let r = Region::open(std::path::Path::new(&args[0]), 4096);
    let mut lats = Vec::new();
    let mut seq = r.u32_at(PING).load(Acquire);
    crate::procs::say_ready();
    loop {
        while r.u32_at(PING).load(Acquire) == seq {
            futex_wait(r.u32_at(PING), seq, Duration::MAX);
        }
        let t = monotonic_ns();
        seq = r.u32_at(PING).load(Acquire);
        if r.u32_at(STOP).load(Acquire) != 0 {
            break;
        }
        lats.push(t.saturating_sub(r.u64_at(PING_T).load(Relaxed)));
        r.u32_at(PONG).fetch_add(1, Release);
        futex_wake_all(r.u32_at(PONG));
    }
    let out: String = lats.iter().map(|l| format!("lat {l}\n")).collect();
    print!("{out}");
}

/// Slots of the raw baseline's sample rings (as many as the wake port's chunks).
const RAW_SLOTS: usize = 64;
/// Bytes of one channel's ring in the raw baseline's region.
const RAW_RING_BYTES: usize = RAW_SLOTS * WAKE_NFPC as usize * 4;
/// The raw baseline's region: a page of control words, then one ring per channel (2).
const RAW_REGION_BYTES: usize = 4096 + 2 * RAW_RING_BYTES;

/// Byte offset of channel `c`'s block for wake number `seq` in the raw baseline's region.
pub(super) fn raw_block(c: usize, seq: u32) -> usize {
    4096 + c * RAW_RING_BYTES + (seq as usize % RAW_SLOTS) * WAKE_NFPC as usize * 4
}

/// Raw-futex baseline for many waiters: `readers` processes blocked in FUTEX_WAIT on one
/// shared word; per wake the parent stamps CLOCK_MONOTONIC, bumps the word and issues one
/// FUTEX_WAKE of all of them, exactly the system calls a bass publish makes, without bass.
///
/// Like a bass publish, the parent first writes a block of the wake port's size (64 frames
/// × 2 channels, one ring per channel, as in a port), and like a bass reader every waiter
/// copies it out (plain `memcpy`s) and takes the time again when it has the data: so the
/// bass readers, which read their chunk and stamp both times, are compared like with like.
/// The ring has [`RAW_SLOTS`] slots, so the parent never writes a block a waiter may still
/// be copying.
pub(super) struct RawBroadcast {
    path: std::path::PathBuf,
    region: Region,
    kids: Vec<Child>,
    block: Vec<i32>,
}

impl RawBroadcast {
    pub(super) fn start(readers: usize) -> RawBroadcast {
        let path = bassport::paths::runtime_dir().join("bench-futex-n");
        let region = Region::create(&path, RAW_REGION_BYTES);
        let kids = spawn_ready(readers, "futex-waiter", &[path.display().to_string()]);
        RawBroadcast { path, region, kids, block: vec![7; WAKE_NFPC as usize] }
    }

    /// Writes the next block, then wakes every waiter, stamped with the current time.
    pub(super) fn wake(&self) {
        let next = self.region.u32_at(PING).load(Relaxed).wrapping_add(1);
        for c in 0..2 {
            // SAFETY: `raw_block` is inside the region (RAW_REGION_BYTES) and holds WAKE_NFPC
            // samples; no waiter reads this slot now (it was last published RAW_SLOTS wakes
            // ago, and every waiter copies its block right after waking).
            unsafe {
                std::ptr::copy_nonoverlapping(
                    self.block.as_ptr(),
                    self.region.ptr().add(raw_block(c, next)) as *mut i32,
                    self.block.len(),
                )
            };
        }
        self.region.u64_at(PING_T).store(monotonic_ns(), Relaxed);
        self.region.u32_at(PING).fetch_add(1, Release);
        futex_wake_all(self.region.u32_at(PING));
    }

    /// Stops the waiters; returns their latencies and their median CPU time per wake.
    pub(super) fn finish(self) -> Samples {
        self.region.u32_at(STOP).store(1, Release);
        self.region.u32_at(PING).fetch_add(1, Release);
        futex_wake_all(self.region.u32_at(PING));
        let lines = finish_all(self.kids);
        let _ = std::fs::remove_file(&self.path);
        samples_of(&lines)
    }
}

/// Child: one waiter of the raw-futex broadcast baseline; prints `seq latency_ns data_ns`
/// per wake (woken; block copied out).
pub fn child_futex_waiter(args: &[String]) {
    let r = Region::open(std::path::Path::new(&args[0]), RAW_REGION_BYTES);
    let mut seq = r.u32_at(PING).load(Acquire);
    let (mut left, mut right) = (vec![0i32; WAKE_NFPC as usize], vec![0i32; WAKE_NFPC as usize]);
    let mut out = String::new();
    crate::procs::say_ready();
    let cpu0 = crate::procs::process_cpu_ns();
    loop {
        while r.u32_at(PING).load(Acquire) == seq {
            futex_wait(r.u32_at(PING), seq, Duration::MAX);
        }
        let t = monotonic_ns();
        seq = r.u32_at(PING).load(Acquire);
        if r.u32_at(STOP).load(Acquire) != 0 {
            break;
        }
        for (c, buf) in [&mut left, &mut right].into_iter().enumerate() {
            // SAFETY: the block is inside the region and holds WAKE_NFPC samples; the parent
            // wrote it before the Release increment of PING that this process loaded with
            // Acquire, and does not write that slot again for RAW_SLOTS wakes.
            unsafe {
                std::ptr::copy_nonoverlapping(
                    r.ptr().add(raw_block(c, seq)) as *const i32,
                    buf.as_mut_ptr(),
                    buf.len(),
                )
            };
            std::hint::black_box(&buf);
        }
        let data = monotonic_ns();
        let published = r.u64_at(PING_T).load(Relaxed);
        out.push_str(&format!("{seq} {} {}\n", t.saturating_sub(published), data.saturating_sub(published)));
    }
    out.push_str(&format!(
        "cpu_ns={} chunks={}\n",
        crate::procs::process_cpu_ns() - cpu0,
        out.lines().count()
    ));
    print!("{out}");
}

/// Child: like `wake-reader`, but blocks with a bare FUTEX_WAIT on the port header's futex
/// word (read-only mapping) instead of `Port::wait`.
pub fn child_raw_waiter(args: &[String]) {
    use bassport::format::Header;
    use std::mem::offset_of;
    let port = Port::open(&args[0]).expect("open port");
    let map = Region::open_ro(port.path(), 4096);
    let futex = map.u32_at(offset_of!(Header, futex));
    let lfi_word = map.u64_at(offset_of!(Header, last_frame_index));
    let state = map.u32_at(offset_of!(Header, state));
    let mut nfr = port.info().expect("info").last_frame_index + 1;
    let cap = port.geometry().frames_per_chunk as usize * 8;
    let (mut l, mut r) = (vec![0i32; cap], vec![0i32; cap]);
    let mut out = String::new();
    // Experiment knobs (not used by the harness itself).
    let timeout = match std::env::var("BENCH_WAITER_TIMEOUT_MS").ok().and_then(|v| v.parse().ok()) {
        Some(ms) if ms > 0 => Duration::from_millis(ms),
        _ => Duration::MAX,
    };
    let do_fstat = std::env::var("BENCH_WAITER_FSTAT").is_ok();
    crate::procs::say_ready();
    let cpu0 = crate::procs::process_cpu_ns();
    loop {
        if do_fstat {
            let _ = std::fs::metadata(port.path());
        }
        let seq = futex.load(Acquire);
        let lfi = lfi_word.load(Acquire);
        if lfi < nfr {
            if state.load(Acquire) == State::Stopped as u32 {
                break;
            }
            futex_wait(futex, seq, timeout);
            continue;
        }
        let woke = monotonic_ns();
        let mut bufs = [&mut l[..], &mut r[..]];
        port.get_audio_data(cap, &mut nfr, &mut bufs).expect("read");
        let read = monotonic_ns();
        let published = port.chunk_info(lfi).map(|c| c.mono_ns).unwrap_or(0);
        if published > 0 {
            out.push_str(&format!(
                "{lfi} {} {}\n",
                woke.saturating_sub(published),
                read.saturating_sub(published)
            ));
        }
    }
    out.push_str(&format!(
        "cpu_ns={} chunks={}\n",
        crate::procs::process_cpu_ns() - cpu0,
        out.lines().count()
    ));
    print!("{out}");
}
