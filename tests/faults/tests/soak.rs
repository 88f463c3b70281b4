//! Item 11 — accelerated soak: an unpaced writer process publishes ≥ 10^9 frames of the
//! pattern signal (`$BASS_FAULTS_SOAK_FRAMES`, default 4.5·10^9, past 2^32) with three reader processes
//! attached (copy, blocking wait, zero-copy view), every delivered sample checked.
//!
//! Pass: lastFrameIndex monotonic as seen by every reader; per reader delivered + lost =
//! requested = every frame published, 0 corrupted; resident memory flat: anonymous RSS of
//! every process grows by less than 1 MiB between the first sample (after warm-up) and the
//! last (start/end RSS reported).

use std::time::{Duration, Instant};

use bass_faults::{figure, status_kb, Agent};
use bass_test_support::TempDir;

const NFPC: u64 = 4096;

#[test]
#[ignore = "fault suite: run by tests/faults/run.sh"]
fn a_billion_frames_keep_accounting_exact_and_memory_flat() {
    let frames: u64 =
        std::env::var("BASS_FAULTS_SOAK_FRAMES").ok().and_then(|s| s.parse().ok()).unwrap_or(4_500_000_000);
    let chunks = frames.div_ceil(NFPC);
    let dir = TempDir::shm("soak");
    let port = dir.join("bass-soak.port");
    let p = port.to_str().unwrap();
    let mut w = Agent::writer_held(p, 4096, 16, &["--chunks", &chunks.to_string()]);
    let kinds = [("copy", "4096"), ("wait", "8192"), ("view", "4096")];
    let mut readers: Vec<Agent> =
        kinds.iter().map(|(m, n)| Agent::spawn(&["reader", "--port", p, "--mode", m, "--n", n])).collect();
    for r in &mut readers {
        r.expect_line("ready");
    }
    let pids: Vec<u32> = std::iter::once(w.pid()).chain(readers.iter().map(Agent::pid)).collect();
    w.send("go");
    let started = Instant::now();
    // (VmRSS, RssAnon) per process: first sample after 1 s of warm-up, and the last one.
    let mut first: Vec<Option<(u64, u64)>> = vec![None; pids.len()];
    let mut last: Vec<(u64, u64)> = vec![(0, 0); pids.len()];
    while w.child.try_wait().unwrap().is_none() {
        std::thread::sleep(Duration::from_millis(200));
        for (k, &pid) in pids.iter().enumerate() {
            let s = (status_kb(pid, "VmRSS"), status_kb(pid, "RssAnon"));
            if s.0 == 0 {
                continue;
            }
            if started.elapsed() >= Duration::from_secs(1) && first[k].is_none() {
                first[k] = Some(s);
            }
            last[k] = s;
        }
    }
    let wf = w.result();
    let secs = started.elapsed().as_secs_f64();
    let published = wf.u("last");
    assert!(published >= frames, "published {published} < {frames}");
    for (k, r) in readers.into_iter().enumerate() {
        let f = r.result();
        figure!(
            11,
            "reader {:?}: delivered={} lost={} corrupted={} requested={} lfi_regressions={} view_overwritten={}",
            kinds[k],
            f.u("delivered"),
            f.u("lost"),
            f.u("corrupted"),
            f.u("requested"),
            f.u("lfi_regressions"),
            f.u("view_overwritten")
        );
        assert_eq!(f.u("corrupted"), 0, "reader {k} got corrupted samples");
        assert_eq!(f.u("lfi_regressions"), 0, "reader {k} saw lastFrameIndex go backwards");
        assert_eq!(f.u("requested"), published, "reader {k} must cover every frame");
        assert_eq!(f.u("delivered") + f.u("lost"), published, "reader {k} accounting");
    }
    let names = ["writer", "copy reader", "wait reader", "view reader"];
    let mut rss = Vec::new();
    for k in 0..pids.len() {
        let (s, e) = (first[k].unwrap_or(last[k]), last[k]);
        rss.push(format!("{}: VmRSS {} -> {} kB, RssAnon {} -> {} kB", names[k], s.0, e.0, s.1, e.1));
        assert!(e.1 <= s.1 + 1024, "{}: anonymous memory grew from {} kB to {} kB", names[k], s.1, e.1);
    }
    figure!(
        11,
        "{published} frames ({} chunks of {NFPC}) in {secs:.1} s ({:.0} Mframes/s) with 3 readers attached; {}",
        wf.u("chunks"),
        published as f64 / secs / 1e6,
        rss.join("; ")
    );
}
