//! Acquire requests and reading a broker's port in tests.

use std::path::Path;

use bassport::control::AcquireRequest;
use bassport::Port;

use crate::PATIENCE;

/// An Acquire request (native sample format).
pub fn acquire_req(device: &str, rate: u32, nfpc: u32, ncop: u32, channels: u32) -> AcquireRequest {
    AcquireRequest {
        device: device.into(),
        sample_rate: rate,
        frames_per_chunk: nfpc,
        chunks_on_port: ncop,
        channels,
        format: None,
        followers: Vec::new(),
    }
}

/// Extra `bassd` arguments that let clients replay WAV files from `dir` (`sim:file:` and
/// `sim:file-loop:`). The broker's device policy refuses file replay by default; every
/// replay test gets the operator's widening from this one place.
pub fn replay_args(dir: &Path) -> Vec<String> {
    let d = dir.display();
    vec![
        "--allow-device".into(),
        format!("sim:file:{d}/*"),
        "--allow-device".into(),
        format!("sim:file-loop:{d}/*"),
        "--allow-device".into(),
        format!("sim:file-renumber:{d}/*"),
    ]
}

/// Reads frames `first..=last` of every channel (the frames must still be on the port).
pub fn read_frames(port: &Port, first: u64, last: u64) -> Vec<Vec<i32>> {
    let ch = port.geometry().channels as usize;
    let n = usize::try_from(last + 1 - first).expect("a frame count that fits in memory");
    let mut bufs = vec![vec![0i32; n]; ch];
    let mut nfr = first;
    let mut got = 0;
    while got < n {
        let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| &mut b[got..]).collect();
        let r = port.get_audio_data(n - got, &mut nfr, &mut outs).expect("getAudioData");
        assert_eq!(r.loss, 0, "frames {first}..={last} left the window before they were read");
        assert!(r.frames > 0, "frames {first}..={last} are not published");
        got += r.frames;
    }
    bufs
}

/// Waits for frame `frame` on `port` (panics on anything but success within [`PATIENCE`]).
pub fn wait_frame(port: &Port, frame: u64) -> u64 {
    port.wait(frame, PATIENCE).unwrap_or_else(|e| panic!("waiting for frame {frame}: {e}"))
}
