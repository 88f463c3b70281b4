//! The victims: processes to kill mid-call, one that writes through a read-only mapping, one
//! hammered while its port shrinks, and the open-permission probe.

use std::sync::atomic::Ordering;
use std::time::Duration;

use bassport::{Error, Port};
use clap::{Args, ValueEnum};

use super::*;

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(super) enum VictimMode {
    /// Read the whole window in a loop.
    Read,
    /// Wait for a frame that never comes.
    Wait,
}

#[derive(Args)]
pub(super) struct VictimArgs {
    #[command(flatten)]
    port: PortArg,
    #[arg(long, value_enum, default_value_t = VictimMode::Read)]
    mode: VictimMode,
}

/// Opens the port and reads or waits forever, to be SIGKILLed mid-call.
pub(super) fn victim(a: &VictimArgs) {
    let port = open(&a.port);
    let mode = a.mode;
    let nfop = port.frames_on_port() as usize;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; nfop]; channels];
    say!("ready pid={}", std::process::id());
    let mut nfr = 0u64;
    loop {
        if mode == VictimMode::Wait {
            let _ = port.wait(u64::MAX / 4, Duration::from_secs(3600));
        } else {
            let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
            let _ = port.get_audio_data(nfop, &mut nfr, &mut outs);
            nfr = nfr.saturating_sub(nfop as u64);
        }
    }
}

/// Reports how the port is open and mapped, then stores through the read-only mapping:
/// the store must fault (SIGSEGV). Prints SURVIVED and exits 0 if it did not.
pub(super) fn poke(a: &PortArg) {
    let port = open(a);
    let path = std::fs::canonicalize(a.path()).expect("canonicalize");
    let p = path.to_string_lossy().into_owned();
    let maps = std::fs::read_to_string("/proc/self/maps").expect("maps");
    let perms: Vec<&str> = maps
        .lines()
        .filter(|l| l.ends_with(p.as_str()))
        .filter_map(|l| l.split_whitespace().nth(1))
        .collect();
    let mut flags = Vec::new();
    for e in std::fs::read_dir("/proc/self/fd").expect("fd dir").flatten() {
        if std::fs::read_link(e.path()).map(|t| t == path).unwrap_or(false) {
            let info =
                std::fs::read_to_string(format!("/proc/self/fdinfo/{}", e.file_name().to_string_lossy()))
                    .unwrap_or_default();
            if let Some(f) = info.lines().find_map(|l| l.strip_prefix("flags:")) {
                flags.push(f.trim().to_owned());
            }
        }
    }
    say!("MAPPING perms={} open_flags={}", perms.join(","), flags.join(","));
    let ring = port.channel_ring(0).expect("channel 0");
    ring.word_of(0).store(0x5a5a_5a5a_5a5a_5a5a, Ordering::Relaxed);
    say!("SURVIVED");
}

/// Calls every size-dependent library function in a loop until stdin closes, counting
/// outcomes; the test shrinks the file meanwhile. A SIGBUS would kill the process.
pub(super) fn shrink_victim(a: &PortArg) {
    let port = open(a);
    let stop = stdin_stop_flag();
    let nfop = port.frames_on_port() as usize;
    let channels = port.geometry().channels as usize;
    let mut bufs = vec![vec![0i32; nfop]; channels];
    say!("ready pid={}", std::process::id());
    let (mut ok, mut corrupt, mut other, mut calls) = (0u64, 0u64, 0u64, 0u64);
    let mut tally = |r: Result<(), Error>| match r {
        Ok(()) => ok += 1,
        Err(Error::Corrupt(_)) => corrupt += 1,
        Err(_) => other += 1,
    };
    while !stop.load(Ordering::Relaxed) {
        let mut nfr = 0u64;
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        tally(port.get_audio_data(nfop, &mut nfr, &mut outs).map(drop));
        tally(port.info().map(drop));
        tally(port.chunk_info(1).map(drop));
        tally(port.wait(1, Duration::ZERO).map(drop));
        let mut nfr = 0u64;
        tally(port.view(nfop, &mut nfr).map(drop));
        calls += 5;
    }
    // After a SIGBUS caught by the guard the handle stays unusable: a read of the restored
    // file still fails (a size-check Corrupt would pass once the size is back).
    let mut nfr = 0u64;
    let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
    if let Err(Error::Corrupt(m)) = port.get_audio_data(nfop, &mut nfr, &mut outs) {
        if m.contains("shrank under the reader") {
            say!("GUARDED {m}");
        }
    }
    say!("RESULT calls={calls} ok={ok} corrupt={corrupt} other={other}");
}

/// Reports whether this process (typically run under setpriv as another uid) can open the
/// port for reading through the library, and whether it could open the file for writing.
pub(super) fn try_open(a: &PortArg) {
    if let Some(name) = &a.name {
        let read = match Port::open(name) {
            Ok(p) => format!(
                "ok lfi={} sealed={}",
                p.info().map(|i| i.last_frame_index).unwrap_or(0),
                p.size_sealed()
            ),
            Err(Error::NotFound { .. }) => "notfound".to_owned(),
            Err(e) => format!("error:{e}").replace(' ', "_"),
        };
        say!("RESULT uid={} read={read}", rustix::process::getuid().as_raw());
        return;
    }
    let port_path = a.path();
    let read = match Port::open_path(port_path) {
        Ok(p) => format!("ok lfi={}", p.info().map(|i| i.last_frame_index).unwrap_or(0)),
        // The errno, or the kind of an error the library explained (a refusal of access
        // carries its advice, not the errno).
        Err(Error::Io { source, .. }) => match source.raw_os_error() {
            Some(n) => format!("io:{n}"),
            None => format!("io:{:?}", source.kind()),
        },
        Err(e) => format!("error:{e}").replace(' ', "_"),
    };
    let write = match std::fs::OpenOptions::new().write(true).open(port_path) {
        Ok(_) => "ok".to_owned(),
        Err(e) => format!("io:{}", e.raw_os_error().unwrap_or(0)),
    };
    say!("RESULT uid={} read={read} write={write}", rustix::process::getuid().as_raw());
}
