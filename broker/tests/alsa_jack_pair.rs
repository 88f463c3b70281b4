//! Two real ALSA capture devices on one clock (issue 35, "the jack-plugin pair"): a
//! `jackd -d dummy` at 48 kHz, one JACK client playing known tones on two ports
//! ([`TONES`]), and two ALSA `jack` PCMs that both capture those two ports. bassd acquires
//! the pair, the first as the master and the second as a follower (docs/multi-device.md).
//!
//! One clock drives both PCMs and both carry the same samples. After the aligner's window has
//! filled, every second of the follower's channels is compared with the master's: the tones'
//! amplitudes, the follower's delay behind the master from the tones' phases (a whole second
//! holds each whole-Hz tone in a DFT bin of its own; the 7/5 Hz tones make it unambiguous
//! over ±70 ms), and sample by sample the follower against the master's signal at that delay.
//!
//! What it shows (docs/multi-device.md, *The jack-plugin pair*): the follower is the master's
//! signal at a delay within a fraction of a sample to a few samples that wanders slowly —
//! the jitter of the jack plugin's timestamps on this machine — and the aligner seldom locks
//! (its lock threshold is 0.5 sample of a p99.9 estimate). The bounds below are that measured wander with a margin, not
//! the resampler's precision: the lock is reported, not asserted.

use std::f64::consts::TAU;

use bass_test_support::*;
use bassport::control::FollowerRequest;
use bassport::Port;

const RATE: u32 = TONES_RATE;
const NFPC: u32 = 480;
/// jackd's period (frames): long, so that a late cycle seldom restarts the dummy backend's
/// timebase (see [`Jackd::start_sched`]).
const JACK_PERIOD: u32 = 1024;
/// 12 s of frames on the port: the analysed seconds stay readable while the test reads them.
const NCOP: u32 = 1200;
/// The analysis starts this many seconds into the acquisition: the aligner's 4 s window of
/// stamps full, and its controller settled (at 6 s the delay still drifted by 0.1 to 0.75
/// sample per second; at 14 s it stays within ±0.4 sample at load 1).
const SETTLE_S: u64 = 14;
/// Seconds analysed.
const SECONDS: usize = 6;
/// Of those, how many must hold the played tones on the master (a second whose master is not
/// the tones had a glitch in JACK itself — a cycle the tone player missed — seen at load 5;
/// it is left out and counted).
const MIN_CLEAN: usize = 3;

/// An error estimate (Status, polled every 0.5 s) above this many samples is the aligner
/// saying it lost the follower's timing (a JACK glitch on the follower's PCM: its frames
/// jumped, the aligner started a new run; seen once in 8 runs of 2026-12-04 with the
/// estimate at 49.6 samples and the delay at +1255 samples): the seconds around it are left
/// out and counted, as the master's glitches are. It was 5 samples until 2026-12-08: on a
/// busy host (2026-12-07, a fresh-clone CI run and 1 of 3 warm runs) the estimate sat at
/// 6.5–10.3 samples through all six seconds with no restart, and the test left every
/// second out; single polls reach 6.8 (2026-12-08, 9 runs) while the delay stays within
/// ±2.5 samples.
const RESTART_ESTIMATE: f64 = 20.0;

/// Largest |delay| of the follower behind the master, samples (measured: within ±0.4 at load
/// 1 from 14 s; within ±2.7 at load 5 from 6 s; 2026-12-04, the 20 s time lines: within
/// ±2.75 in 11 runs; 2026-12-08, 9 runs idle, one busy core and two: within −2.1 … +2.5;
/// 2026-12-07 on a busy host, with the estimate at 6.5–10 samples: −7.27 and +8.03 in 2 of 5
/// runs). 12 samples is 250 µs; a follower off by a chunk (480) or not the master's signal
/// fails it by far.
const DELAY_BOUND: f64 = 12.0;
/// Largest change of the delay between the analysed seconds, samples (measured: 0.06 to 0.7
/// at load 1 from 14 s; 0.3 to 3.1 at load 5 from 6 s; 0.07 to 4.1, 2026-12-08).
/// A clock error of 100 ppm would move it 29 samples over the 6 s.
const DELAY_SPREAD_BOUND: f64 = 12.0;
/// Largest difference, full scale, between a follower sample and the master's signal at the
/// second's delay: the delay's wander inside the second times the signal's largest slope
/// (0.1 FS per sample). Measured: 0.003 to 0.02 at load 1, up to 0.08 at load 5; with the
/// 20 s time lines (2026-12-04, 11 runs) 0.013 to 0.15 and once 0.216 (CI: the delay moved
/// by 2.5 samples within a second on an idle machine, the ratio swung to −270 ppm).
const RESIDUAL_BOUND: f64 = 0.35;
/// Largest relative difference of a tone's amplitude, follower vs master, over one second: a
/// delay wandering by δ samples (RMS) inside the second lowers a tone of ω rad/sample by
/// about ω²δ²/2 (measured: 0.4 to 5 %, the 4001 Hz tone; 2026-12-04, 11 runs: 0.1 to 8.9 %
/// and once 24.1 %, the CI run above: δ ≈ 1.3 samples RMS). The signal itself is what it
/// bounds: a follower that is not the master's signal is ~100 % off.
const AMPLITUDE_BOUND: f64 = 0.35;
/// |ratio_ppm| allowed in Status (measured: within ±50 ppm while aligning, the controller's
/// corrections of the stamps' jitter; 2026-12-04, 11 runs: within −62..+68 ppm and once −270,
/// the controller (0.25 s) answering a 3-sample step of the time lines; a ratio off by 1000
/// ppm moves the delay 48 samples a second, which the delay bounds catch anyway).
const RATIO_BOUND_PPM: f64 = 400.0;

/// Full scale of a port sample (the jack plugin's floats are stored as S32).
const FS: f64 = 2147483648.0;

/// Each tone's complex amplitude over one whole second of `x` (a DFT bin per whole Hz).
fn tones_of(x: &[f64], tones: &[(u32, f64)]) -> Vec<(f64, f64)> {
    assert_eq!(x.len(), RATE as usize);
    tones
        .iter()
        .map(|&(f, _)| {
            let w = TAU * f64::from(f) / f64::from(RATE);
            let (mut re, mut im) = (0.0, 0.0);
            for (k, v) in x.iter().enumerate() {
                let a = w * k as f64;
                re += v * a.cos();
                im -= v * a.sin();
            }
            let n = x.len() as f64 / 2.0;
            (re / n, im / n)
        })
        .collect()
}

/// The signal of complex tone amplitudes `amps` at (fractional) frame `t` of the window.
fn synth(tones: &[(u32, f64)], amps: &[(f64, f64)], t: f64) -> f64 {
    tones
        .iter()
        .zip(amps)
        .map(|(&(f, _), &(re, im))| {
            let a = TAU * f64::from(f) / f64::from(RATE) * t;
            re * a.cos() - im * a.sin()
        })
        .sum()
}

/// The delay (frames) of `fol` behind `mas` from the tones' phases: coarse from the lowest
/// tone (unambiguous over ±half its period), refined by each higher one.
fn delay(tones: &[(u32, f64)], mas: &[(f64, f64)], fol: &[(f64, f64)]) -> f64 {
    let mut d = 0.0;
    for (i, &(f, _)) in tones.iter().enumerate() {
        let period = f64::from(RATE) / f64::from(f);
        let dphi = mas[i].1.atan2(mas[i].0) - fol[i].1.atan2(fol[i].0);
        let raw = dphi / TAU * period;
        d = if i == 0 {
            raw - (raw / period).round() * period
        } else {
            raw + ((d - raw) / period).round() * period
        };
    }
    d
}

/// One channel's second: its samples and its tones' complex amplitudes.
type Fit = (Vec<f64>, Vec<(f64, f64)>);

fn device(s: &bassport::control::Status, i: usize) -> &bassport::control::DeviceStatus {
    s.devices.get(i).unwrap_or_else(|| panic!("Status has no device {i}: {:?}", s.devices))
}

#[test]
fn two_jack_pcms_on_one_clock_give_the_same_signal_at_a_steady_delay() {
    if skip(jack_missing()) {
        return;
    }
    let pcm = ["bass_tones:out_1", "bass_tones:out_2"];
    let rig = JackRig::with_pcms(
        TempDir::new("jackpair"),
        "bass-test-jackpair",
        &[("bass_jack_a", pcm), ("bass_jack_b", pcm)],
    );
    let _jackd = rig.jackd_rt(RATE, JACK_PERIOD);
    let _tones = JackTones::start("bass_tones", &rig.jack_name).expect("start the tone player");
    // Capture threads at SCHED_FIFO 5: below jackd's (10) and its clients' threads, which must
    // keep the cycles on time (bassd's default, 70, above them, let a cycle run late).
    let b = Bassd::start(
        rig.path(),
        "default",
        &["--allow-device", "bass_jack_a", "--allow-device", "bass_jack_b", "--rt-priority", "5"],
        &rig.env(),
    );
    let mut c = b.client();
    let mut req = acquire_req("bass_jack_a", RATE, NFPC, NCOP, 2);
    req.followers = vec![FollowerRequest { device: "bass_jack_b".into(), channels: 2 }];
    let a = c.acquire(&req).expect("acquire the jack pair");
    assert_eq!(a.format, "FLOAT_LE", "the jack plugin offers FLOAT only");
    let port = b.port();
    assert_eq!(port.geometry().channels, 4, "master 2 + follower 2 channels");

    let first = SETTLE_S * u64::from(RATE) + 1;
    let last = first + (SECONDS as u64) * u64::from(RATE) - 1;
    let (mut ratios, mut estimates) = (Vec::new(), Vec::new());
    let mut k = u64::from(RATE);
    while k < last {
        wait_frame(&port, k);
        let s = c.status().expect("status");
        let f = device(&s, 1);
        assert_ne!(
            f.state,
            "lost",
            "the follower PCM is lost: {:?}\nbassd's log:\n{}",
            s.devices,
            b.log_text()
        );
        if k > first {
            ratios.push((k, f.ratio_ppm));
        }
        estimates.push((k, f.error_estimate));
        k += u64::from(RATE) / 2;
    }
    wait_frame(&port, last);
    let data = read_frames(&port, first, last);
    let s = c.status().expect("status");
    let (m, f) = (device(&s, 0), device(&s, 1));
    assert_eq!((m.role.as_str(), m.first_channel, m.channels), ("master", 0, 2));
    assert_eq!((f.role.as_str(), f.first_channel, f.channels), ("follower", 2, 2));
    ratios.push((last, f.ratio_ppm));
    estimates.push((last, f.error_estimate));
    let masks = chunk_masks(&port, first, last);
    let follower_bits = 0b1100u64;
    let unaligned = masks.iter().filter(|m| m.1 & follower_bits != 0).count();
    assert!(masks.iter().all(|m| m.0 & 0b11 == 0), "the master's channels are never missing");
    let chunks_per_s = (RATE / NFPC) as usize;

    let mut delays = Vec::new();
    let (mut worst_master, mut worst, mut worst_amp) = (0.0f64, 0.0f64, 0.0f64);
    let (mut missing, mut glitched) = (0, Vec::new());
    for sec in 0..SECONDS {
        let r = sec * RATE as usize..(sec + 1) * RATE as usize;
        let signal =
            |c: usize| -> Vec<f64> { data[c][r.clone()].iter().map(|&v| f64::from(v) / FS).collect() };
        // The master first: is this second the played tones?
        let fits: Vec<Fit> = TONES
            .iter()
            .enumerate()
            .map(|(ch, tones)| {
                let mas = signal(ch);
                let am = tones_of(&mas, tones);
                (mas, am)
            })
            .collect();
        let off = fits
            .iter()
            .zip(TONES.iter())
            .map(|((mas, am), tones)| {
                (0..RATE as usize).map(|k| (mas[k] - synth(tones, am, k as f64)).abs()).fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        if off >= 1e-5 {
            glitched.push((sec, off));
            continue;
        }
        // The follower's timing lost by the aligner in this second or half a second after.
        let (s0, s1) = (first + (sec as u64) * u64::from(RATE), first + (sec as u64 + 1) * u64::from(RATE));
        let restart = estimates
            .iter()
            .filter(|&&(k, _)| k >= s0 && k < s1 + u64::from(RATE) / 2)
            .map(|&(_, e)| e)
            .fold(0.0f64, f64::max);
        if restart > RESTART_ESTIMATE {
            glitched.push((sec, restart));
            continue;
        }
        worst_master = worst_master.max(off);
        missing += masks[sec * chunks_per_s..(sec + 1) * chunks_per_s]
            .iter()
            .filter(|m| m.0 & follower_bits != 0)
            .count();
        for (ch, tones) in TONES.iter().enumerate() {
            let (mas, am) = &fits[ch];
            for (i, &(hz, amp)) in tones.iter().enumerate() {
                let got = am[i].0.hypot(am[i].1);
                assert!(
                    (got - amp).abs() < 1e-4,
                    "master channel {ch}, second {sec}: {hz} Hz at {got}, played {amp}"
                );
            }
            let fol = signal(2 + ch);
            let af = tones_of(&fol, tones);
            for i in 0..tones.len() {
                let (gm, gf) = (am[i].0.hypot(am[i].1), af[i].0.hypot(af[i].1));
                worst_amp = worst_amp.max((gf / gm - 1.0).abs());
            }
            let d = delay(tones, am, &af);
            delays.push(d);
            let _ = mas;
            for (k, v) in fol.iter().enumerate() {
                worst = worst.max((v - synth(tones, am, k as f64 - d)).abs());
            }
        }
    }
    assert!(
        SECONDS - glitched.len() >= MIN_CLEAN,
        "only {} of {SECONDS} seconds clean (glitches in JACK: second, the master's worst departure from its tones or the follower's error estimate {glitched:?})",
        SECONDS - glitched.len()
    );
    let (lo, hi) = delays.iter().fold((f64::MAX, f64::MIN), |(l, h), &d| (l.min(d), h.max(d)));
    // Status's ratio up to the first glitch (after one the aligner starts again).
    let clean_until = glitched.first().map_or(u64::MAX, |&(sec, _)| first + sec as u64 * u64::from(RATE));
    let ratios: Vec<f64> = ratios.iter().filter(|&&(k, _)| k < clean_until).map(|&(_, r)| r).collect();
    let (rlo, rhi) = ratios.iter().fold((f64::MAX, f64::MIN), |(l, h), &r| (l.min(r), h.max(r)));
    eprintln!(
        "jack pair, seconds {SETTLE_S}..{} ({} with a glitch in JACK left out (second, master's departure or follower's estimate): {glitched:?}): follower {} (locks {}, error estimate {:.3} sample); ratio_ppm {rlo:+.1}..{rhi:+.1}; delay behind the master {lo:+.3}..{hi:+.3} samples (per second and channel: {}); worst |master - its tones| {worst_master:.1e} FS; worst |follower - master at the delay| {worst:.4} FS; follower's tone amplitudes within {:.1} % of the master's; chunks with the follower missing {missing} (in the clean seconds), unaligned {unaligned} of {}",
        SETTLE_S as usize + SECONDS,
        glitched.len(),
        f.state,
        f.locks,
        f.error_estimate,
        delays.iter().map(|d| format!("{d:+.2}")).collect::<Vec<_>>().join(" "),
        worst_amp * 100.0,
        masks.len()
    );
    assert!(worst_master < 1e-5, "the master's channels are not the played tones (worst {worst_master})");
    assert!(worst_amp <= AMPLITUDE_BOUND, "the follower's tones are {worst_amp} off the master's");
    assert_eq!(missing, 0, "chunks of the clean seconds with the follower's channels missing");
    assert!(lo >= -DELAY_BOUND && hi <= DELAY_BOUND, "the follower's delay: {delays:?}");
    assert!(hi - lo <= DELAY_SPREAD_BOUND, "the follower's delay wanders: {delays:?}");
    assert!(worst <= RESIDUAL_BOUND, "follower vs master at the delay: worst {worst} FS");
    for r in ratios {
        assert!(r.abs() <= RATIO_BOUND_PPM, "ratio {r} ppm on one clock");
    }
}

/// `(missing_channels, unaligned_channels)` of every chunk of frames `first..=last`.
fn chunk_masks(port: &Port, first: u64, last: u64) -> Vec<(u64, u64)> {
    let mut v = Vec::new();
    let mut k = first;
    while k <= last {
        let c = port.chunk_info(k).expect("chunk info");
        v.push((c.missing_channels, c.unaligned_channels));
        k = c.first_frame + u64::from(c.frames);
    }
    v
}
