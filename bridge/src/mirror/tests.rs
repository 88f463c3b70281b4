//! The mirror's message handling driven in-process (no Zenoh) against real replica ports in
//! a temporary runtime directory: the defence rules one by one, then a property test with
//! arbitrary message sequences.

use std::collections::HashMap;
use std::path::PathBuf;

use bass_test_support::TempDir;
use bassport::format::chunk_flags;
use bassport::{Port, State};
use proptest::prelude::*;

use super::bounds::Bounds;
use super::core::{
    Core, MirrorStatus, Outcome, GONE_SILENCE_NS, INSTANCE_SILENCE_NS, RETRY_NS, STATE_CONFIRM_NS,
};
use crate::clock::ClockMap;
use crate::wire::{self, Header};

const RATE: u32 = 48_000;
const NFPC: u32 = 32;
const NCOP: u32 = 8;
const SEC: u64 = 1_000_000_000;
const T0: u64 = 1_000 * SEC;

fn header(instance: u64, epoch: u64, first_frame: u64) -> Header {
    Header {
        magic: wire::MAGIC,
        version: wire::VERSION,
        header_len: wire::HEADER_LEN as u16,
        flags: 0,
        instance,
        epoch,
        sequence: 0,
        first_frame,
        frames: NFPC,
        channels: 2,
        sample_format: wire::SAMPLE_FORMAT_S32,
        sample_rate: RATE,
        chunks_on_port: NCOP,
        mono_ns: 0,
        realtime_ns: 0,
        send_mono_ns: 0,
        source_lost: 0,
        bound_ns: bassport::format::BOUND_UNKNOWN,
        missing_channels: 0,
        unaligned_channels: 0,
    }
}

/// Samples no other chunk has: instance, epoch and frame in every value (never 0 or i32::MAX).
fn signature(instance: u64, epoch: u64, first_frame: u64) -> Vec<i32> {
    (0..(NFPC * 2) as u64)
        .map(|i| (((instance * 131 + epoch * 17 + first_frame * 2 + i) % 1_000_000_000) as i32) + 1)
        .collect()
}

fn chunk(instance: u64, epoch: u64, first_frame: u64) -> Vec<u8> {
    wire::encode(&header(instance, epoch, first_frame), &signature(instance, epoch, first_frame))
}

/// A source state message.
fn state(state: &str, message: &str, epoch: u64) -> Vec<u8> {
    let s = crate::net::SourceState {
        state: serde_json::from_value(serde_json::Value::from(state)).unwrap(),
        message: message.into(),
        epoch,
        error_code: if state == "error" { 5 } else { 0 },
        ..Default::default()
    };
    serde_json::to_vec(&s).unwrap()
}

struct Rig {
    dir: TempDir,
    core: Core,
}

impl Rig {
    fn new(tag: &str) -> Rig {
        let dir = TempDir::shm(tag);
        let st = MirrorStatus { replica: "rep".into(), source: "src".into(), ..Default::default() };
        let core = Core::new(dir.join("bass-rep.port"), Bounds::default(), st, T0);
        Rig { dir, core }
    }

    fn port_path(&self) -> PathBuf {
        self.dir.join("bass-rep.port")
    }

    fn send(&mut self, bytes: &[u8], now: u64) -> Outcome {
        let out = self.core.on_message(bytes, now, None);
        assert_eq!(out.len(), 1);
        out[0]
    }

    fn message(&self) -> String {
        Port::open_path(&self.port_path()).unwrap().info().unwrap().message
    }
}

fn applied(o: Outcome) -> bool {
    matches!(o, Outcome::Applied { .. })
}

#[test]
fn a_1_tib_geometry_is_refused_and_nothing_is_allocated() {
    let mut r = Rig::new("huge");
    // A header asking for 64 channels x 2^20 frames x 4095 chunks (~1 TiB): a GAP chunk, so
    // the decoder takes it; the format's own size limit refuses it (before the operator's
    // bounds, as in bassd: no option could widen it).
    let h = Header {
        channels: 64,
        frames: 1 << 20,
        chunks_on_port: 4095,
        flags: wire::flags::GAP,
        ..header(1, 1, 1)
    };
    let msg = wire::encode(&h, &[]);
    assert_eq!(msg.len(), wire::HEADER_LEN);
    assert_eq!(r.send(&msg, T0), Outcome::Invalid);
    assert_eq!(r.core.st.invalid_messages, 1);
    assert!(r.dir.entries().is_empty(), "nothing made: {:?}", r.dir.entries());
    let err = r.core.st.error.clone().unwrap();
    assert!(err.contains("cannot make the replica") && err.contains("exceeds the format's limit"), "{err}");
    // The real source then gets its replica, and the error goes.
    assert!(applied(r.send(&chunk(1, 1, 1), T0 + 1)));
    assert_eq!(r.core.st.error, None);
}

#[test]
fn a_chunk_at_frame_2_pow_62_is_refused_and_does_not_freeze_the_replica() {
    let mut r = Rig::new("far");
    let n = u64::from(NFPC);
    for k in 0..4 {
        assert!(applied(r.send(&chunk(1, 1, 1 + k * n), T0 + k * 1_000_000)));
    }
    let far = (wire::MAX_FRAMES as u64) << 20; // aligned, and below the format's limit
    let far = (bassport::format::MAX_FRAME_INDEX - far) / n * n + 1;
    assert_eq!(r.send(&chunk(1, 1, far), T0 + 5_000_000), Outcome::FarFrame);
    assert_eq!(r.core.st.refused_far_frames, 1);
    // The real stream goes on where it was.
    assert_eq!(
        r.send(&chunk(1, 1, 1 + 4 * n), T0 + 6_000_000),
        Outcome::Applied { gap: 0, new_replica: false }
    );
    assert_eq!(r.core.writer().unwrap().last_frame_index(), 5 * n);
    // After a real outage of 60 s the jump the time allows is taken as GAP.
    let later = 1 + 4 * n + 60 * u64::from(RATE);
    assert!(applied(r.send(&chunk(1, 1, later), T0 + 66 * SEC)));
}

#[test]
fn two_sources_with_one_name_are_an_error_naming_both_without_phantom_loss() {
    let mut r = Rig::new("two");
    let n = u64::from(NFPC);
    let (a, b) = (0xaaaa, 0xbbbb);
    let mut t = T0;
    for k in 0..200u64 {
        // Both robots publish the same frames of their own streams, interleaved.
        assert!(applied(r.send(&chunk(a, 3, 1 + k * n), t)));
        assert_eq!(r.send(&chunk(b, 7, 1 + k * n), t + 1), Outcome::OtherSource);
        t += 666_666;
    }
    let st = &r.core.st;
    assert_eq!((st.refused_other_source, st.gap_frames_lost, st.replica_recreations), (200, 0, 1));
    assert_eq!(st.two_sources, vec!["000000000000aaaa".to_string(), "000000000000bbbb".to_string()]);
    assert!(st.error.as_deref().unwrap().contains("two sources"));
    let msg = r.message();
    assert!(msg.contains("000000000000aaaa") && msg.contains("000000000000bbbb"), "{msg}");
    assert_eq!(r.core.writer().unwrap().state(), State::Capturing, "the followed source goes on");
    // The followed one goes silent (its serve restarted): the other one is taken.
    t += INSTANCE_SILENCE_NS;
    assert_eq!(r.send(&chunk(b, 7, 1 + 200 * n), t), Outcome::Applied { gap: 0, new_replica: true });
    // And five seconds later the two-sources error is over.
    r.core.tick(t + 6 * SEC, 100 * SEC, true);
    assert!(r.core.st.two_sources.is_empty() && r.core.st.error.is_none());
}

#[test]
fn fifty_new_epochs_make_at_most_one_replica_a_second_and_five_a_minute() {
    let mut r = Rig::new("epochs");
    let mut t = T0;
    for e in 1..=50u64 {
        r.send(&chunk(1, e, 1), t);
        t += 10_000_000;
    }
    assert_eq!((r.core.st.replica_recreations, r.core.st.refused_epochs), (1, 49));
    // One a second at most, five a minute: 30 s of a new epoch every 100 ms.
    for e in 100..400u64 {
        r.send(&chunk(1, e, 1), t);
        t += 100_000_000;
    }
    assert_eq!(r.core.st.replica_recreations, 5, "within the first minute");
    assert!(std::fs::metadata(r.port_path()).unwrap().len() < 1 << 20);
}

#[test]
fn a_forged_stopped_state_while_chunks_flow_is_ignored_and_a_real_stop_applies() {
    let mut r = Rig::new("state");
    let n = u64::from(NFPC);
    let mut t = T0;
    assert!(applied(r.send(&chunk(1, 1, 1), t)));
    let stopped = &state("stopped", "", 1);
    r.core.on_state(stopped, t);
    t += 1_000_000;
    assert!(applied(r.send(&chunk(1, 1, 1 + n), t)));
    r.core.tick(t + STATE_CONFIRM_NS, 100 * SEC, true);
    assert_eq!(r.core.writer().unwrap().state(), State::Capturing);
    assert_eq!(r.core.st.refused_states, 1);
    // A real stop: no chunk after it.
    r.core.on_state(stopped, t + 2_000_000);
    r.core.tick(t + 2_000_000 + STATE_CONFIRM_NS, 100 * SEC, true);
    assert_eq!(r.core.writer().unwrap().state(), State::Stopped);
}

#[test]
fn text_from_the_source_reaches_the_port_escaped() {
    let mut r = Rig::new("escape");
    assert!(applied(r.send(&chunk(1, 1, 1), T0)));
    let evil = state("error", "\u{1b}]0;owned\u{7}\u{1b}[2J\r\nfake", 1);
    r.core.on_state(&evil, T0 + 1);
    r.core.tick(T0 + 1 + STATE_CONFIRM_NS, 100 * SEC, true);
    let msg = r.message();
    assert!(!msg.chars().any(char::is_control), "{msg:?}");
    assert!(msg.contains("\\x1b]0;owned\\x07"), "{msg:?}");
}

#[test]
fn a_replica_that_cannot_be_made_is_an_error_state_retried_later_never_an_exit() {
    let dir = TempDir::shm("retry");
    let missing = dir.join("not-yet");
    let st = MirrorStatus { source: "src".into(), ..Default::default() };
    let mut core = Core::new(missing.join("bass-rep.port"), Bounds::default(), st, T0);
    let n = u64::from(NFPC);
    assert_eq!(core.on_message(&chunk(1, 1, 1), T0, None), vec![Outcome::Failed]);
    let err = core.st.error.clone().unwrap();
    assert!(err.contains("cannot make the replica port"), "{err}");
    std::fs::create_dir(&missing).unwrap();
    // Not before the retry interval; then it is made.
    assert_eq!(core.on_message(&chunk(1, 1, 1 + n), T0 + 1, None), vec![Outcome::Failed]);
    let o = core.on_message(&chunk(1, 1, 1 + 2 * n), T0 + RETRY_NS, None);
    assert_eq!(o, vec![Outcome::Applied { gap: 0, new_replica: true }]);
    assert_eq!(core.st.error, None);
}

// --- the property test ---

#[derive(Clone, Debug)]
enum Op {
    /// A chunk of instance `inst` (0..3), epoch `epoch`, `step` chunks after that stream's
    /// cursor (3 = two chunks back: late).
    Chunk { inst: u64, epoch: u64, step: u64 },
    /// The last message again.
    Dup,
    /// A chunk of instance `inst` at its epoch 1, 2^40 frames ahead.
    Far { inst: u64 },
    /// A chunk of a forged instance with i32::MAX samples at the followed stream's next frame.
    Forged,
    /// A 1 TiB geometry.
    Huge,
    /// Bytes that are not a message.
    Garbage(Vec<u8>),
    /// A state message (0 stopped, 1 error, 2 gone, 3 capturing) for the current epoch.
    State(u8),
    /// Time passes (ms).
    Advance(u64),
    /// The liveliness token of instance `inst` goes away (its serve exited, or a forgery).
    TokenGone(u64),
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        8 => (0u64..3, 1u64..4, 0u64..4).prop_map(|(inst, epoch, step)| Op::Chunk { inst, epoch, step }),
        1 => Just(Op::Dup),
        1 => (0u64..3).prop_map(|inst| Op::Far { inst }),
        1 => Just(Op::Forged),
        1 => Just(Op::Huge),
        1 => proptest::collection::vec(any::<u8>(), 0..200).prop_map(Op::Garbage),
        1 => (0u8..4).prop_map(Op::State),
        2 => prop_oneof![0u64..50, 0u64..3000].prop_map(Op::Advance),
        1 => (0u64..3).prop_map(Op::TokenGone),
    ]
}

/// Instance ids of the model's instances.
fn id(inst: u64) -> u64 {
    0x1000 + inst
}
const FORGED: u64 = 0xf0f0;

proptest! {
    #![proptest_config(ProptestConfig { cases: 1024, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_message_sequences_leave_only_accepted_chunks_in_the_replica(
        ops in proptest::collection::vec(op(), 1..80)
    ) {
        let mut r = Rig::new("prop");
        let n = u64::from(NFPC);
        let mut now = T0;
        let mut cursor: HashMap<(u64, u64), u64> = HashMap::new();
        let mut last: Option<Vec<u8>> = None;
        // The model: what the core accepted, for the replica it made last.
        let mut frames: HashMap<u64, Option<Vec<i32>>> = HashMap::new(); // chunk first frame -> samples (None = GAP)
        let mut epoch_of_replica: Option<u64> = None;
        let mut followed: Option<(u64, u64)> = None; // instance, last heard
        let mut token_gone = false; // the followed instance's token went away
        let mut creations: Vec<u64> = Vec::new();
        let mut applied_count = 0u64;
        let mut gap_sum = 0u64;
        let mut last_applied_epoch = 0u64;
        for op in ops {
            now += 700_000; // a chunk period passes between messages
            let (bytes, inst, samples, first, epoch) = match &op {
                Op::Chunk { inst, epoch, step } => {
                    let c = cursor.entry((*inst, *epoch)).or_insert(1);
                    let first = if *step == 3 { c.saturating_sub(2 * n).max(1) } else { *c + step * n };
                    *c = (*c).max(first + n);
                    let s = signature(id(*inst), *epoch, first);
                    (wire::encode(&header(id(*inst), *epoch, first), &s), Some(id(*inst)), Some(s), first, *epoch)
                }
                Op::Dup => match &last { Some(b) => {
                    // (a repeated 1 TiB message is refused again: not a chunk of the model)
                    let c = wire::decode(b).ok().filter(|c| c.header.channels == 2);
                    let (i, s, f, e) = c.map(|c| (Some(c.header.instance), Some(c.planar()), c.header.first_frame, c.header.epoch))
                        .unwrap_or((None, None, 0, 0));
                    (b.clone(), i, s, f, e)
                } None => continue },
                Op::Far { inst } => {
                    let first = (1u64 << 40) + 1;
                    let s = signature(id(*inst), 1, first);
                    (wire::encode(&header(id(*inst), 1, first), &s), Some(id(*inst)), Some(s), first, 1)
                }
                Op::Forged => {
                    let e = last_applied_epoch.max(1);
                    let first = followed.and_then(|(i, _)| cursor.get(&(i - 0x1000, e)).copied()).unwrap_or(1);
                    let s = vec![i32::MAX; (n * 2) as usize];
                    (wire::encode(&header(FORGED, e, first), &s), Some(FORGED), Some(s), first, e)
                }
                Op::Huge => {
                    let h = Header { channels: 64, frames: 1 << 20, chunks_on_port: 4095, flags: wire::flags::GAP, ..header(id(0), 1, 1) };
                    (wire::encode(&h, &[]), None, None, 0, 0)
                }
                Op::Garbage(b) => (b.clone(), None, None, 0, 0),
                Op::State(k) => {
                    let st = ["stopped", "error", "gone", "capturing"][*k as usize];
                    r.core.on_state(&state(st, "\u{1b}[2J", last_applied_epoch), now);
                    continue;
                }
                Op::TokenGone(i) => {
                    r.core.on_token(id(*i), false);
                    if followed.is_some_and(|(f, _)| f == id(*i)) {
                        token_gone = true;
                    }
                    continue;
                }
                Op::Advance(ms) => {
                    now += ms * 1_000_000;
                    r.core.tick(now, 2 * SEC, true);
                    continue;
                }
            };
            last = Some(bytes.clone());
            let outs = r.core.on_message(&bytes, now, None);
            prop_assert_eq!(outs.len(), 1);
            let o = outs[0];
            let Some(inst) = inst else {
                prop_assert_eq!(o, Outcome::Invalid);
                continue;
            };
            // Who may be applied: the followed instance, or another once it was silent.
            let silence = if token_gone { GONE_SILENCE_NS } else { INSTANCE_SILENCE_NS };
            let switch_ok = followed.map_or(true, |(f, heard)| f == inst || now - heard >= silence);
            if matches!(o, Outcome::Applied { .. } | Outcome::LateOrDuplicate) && followed.is_some_and(|(f, _)| f != inst) {
                token_gone = false;
            }
            match o {
                Outcome::Applied { gap, new_replica } => {
                    prop_assert!(switch_ok, "{:x} applied while {:x?} was heard", inst, followed);
                    if new_replica {
                        if let Some(&prev) = creations.last() {
                            prop_assert!(now - prev >= SEC, "two replicas within a second");
                        }
                        creations.push(now);
                        let in_minute = creations.iter().filter(|&&t| now - t < 60 * SEC).count();
                        prop_assert!(in_minute <= 5, "{} replicas within a minute", in_minute);
                        frames.clear();
                        epoch_of_replica = Some(epoch);
                    }
                    prop_assert_eq!(epoch_of_replica, Some(epoch));
                    prop_assert!(new_replica || first < (1u64 << 40), "a chunk 2^40 frames ahead was applied");
                    // The gap frames: zeros, whole chunks before this one.
                    for k in 0..gap / n {
                        frames.insert(first - gap + k * n, None);
                    }
                    frames.insert(first, samples.clone());
                    gap_sum += gap;
                    applied_count += 1;
                    last_applied_epoch = epoch;
                    followed = Some((inst, now));
                }
                Outcome::LateOrDuplicate => {
                    prop_assert!(switch_ok);
                    followed = Some((inst, now));
                }
                Outcome::OtherSource => {
                    prop_assert!(!switch_ok, "refused as a second source though the followed one was silent");
                }
                Outcome::Invalid => prop_assert!(false, "a valid chunk refused as invalid"),
                Outcome::FarFrame | Outcome::RefusedEpoch | Outcome::Failed => {
                    if let Some((f, _)) = followed {
                        if f == inst { followed = Some((f, now)); }
                    }
                }
            }
        }
        let st = &r.core.st;
        prop_assert_eq!(st.chunks_written, applied_count);
        prop_assert_eq!(st.gap_frames_lost, gap_sum);
        prop_assert_eq!(st.replica_recreations, creations.len() as u64);
        // Memory bounded: never a file beyond the bounds, at most the port itself.
        for e in r.dir.entries() {
            let len = std::fs::metadata(r.dir.join(&e)).unwrap().len();
            prop_assert!(len <= Bounds::default().max_port_bytes, "{} is {} bytes", e, len);
            prop_assert_eq!(e, "bass-rep.port");
        }
        // The replica holds exactly what was accepted, and a reader's accounting is exact.
        if epoch_of_replica.is_some() {
            let port = Port::open_path(&r.port_path()).unwrap();
            let lfi = port.info().unwrap().last_frame_index;
            let mut nfr = 1u64;
            let (mut delivered, mut lost) = (0u64, 0u64);
            let fop = port.frames_on_port() as usize;
            let (mut left, mut right) = (vec![0i32; fop], vec![0i32; fop]);
            while nfr <= lfi {
                let before = nfr;
                let rd = port.get_audio_data(fop, &mut nfr, &mut [&mut left, &mut right]).unwrap();
                let start = before + rd.loss;
                for i in 0..rd.frames {
                    let f = start + i as u64;
                    let c = (f - 1) / n * n + 1;
                    // Planar on the wire: channel 0's frames, then channel 1's.
                    let k = (f - c) as usize;
                    match frames.get(&c) {
                        Some(Some(s)) => {
                            prop_assert_eq!((left[i], right[i]), (s[k], s[k + n as usize]), "frame {}", f);
                        }
                        Some(None) => {
                            prop_assert_eq!((left[i], right[i]), (0, 0));
                            let info = port.chunk_info(f).unwrap();
                            prop_assert!(info.flags & chunk_flags::GAP != 0, "zeros not marked GAP at {}", f);
                        }
                        None => prop_assert!(false, "frame {} delivered but never accepted", f),
                    }
                }
                delivered += rd.frames as u64;
                lost += rd.loss;
                if rd.frames == 0 && rd.loss == 0 { break; }
            }
            prop_assert_eq!(delivered + lost, lfi, "accounting from frame 1 to {}", lfi);
        }
    }
}

#[test]
fn duration_options_refuse_inf_nan_huge_and_negative_values_naming_the_option() {
    use clap::Parser;
    #[derive(Parser, Debug)]
    struct Cli {
        #[command(flatten)]
        m: super::MirrorOpts,
    }
    for opt in ["--timeout", "--probe-interval"] {
        for v in ["inf", "1e300", "NaN", "-1", "0", "-inf", "x"] {
            let arg = format!("{opt}={v}");
            let e = Cli::try_parse_from(["mirror", arg.as_str(), "--insecure"]).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{arg}");
            assert!(e.to_string().contains(opt), "{arg}: {e}");
        }
        let arg = format!("{opt}=0.25");
        assert!(Cli::try_parse_from(["mirror", arg.as_str()]).is_ok(), "{arg}");
    }
}

#[test]
fn the_replica_names_its_source_and_carries_the_sources_rate_estimate() {
    let mut r = Rig::new("rate");
    let n = u64::from(NFPC);
    // The source's clock runs 100 ppm fast of nominal: 48 004.8 frames per source second.
    let per_chunk_ns = (n as f64 * 1e9 / 48_004.8) as u64;
    for k in 0..3000u64 {
        let h = Header { mono_ns: 5 * SEC + k * per_chunk_ns, ..header(1, 4, 1 + k * n) };
        let msg = wire::encode(&h, &signature(1, 4, 1 + k * n));
        assert!(applied(r.send(&msg, T0 + k * 666_000)));
    }
    let info = Port::open_path(&r.port_path()).unwrap().info().unwrap();
    assert_eq!(info.device, "bass-bridge mirror of src (source epoch 4)");
    assert!((info.rate_estimate_hz - 48_004.8).abs() < 0.5, "rate estimate {}", info.rate_estimate_hz);
}

#[test]
fn a_silent_source_is_said_once_per_silence_with_or_without_a_replica() {
    let mut r = Rig::new("silent");
    let timeout = 2 * SEC;
    assert_eq!(r.core.tick(T0 + SEC, timeout, false), None);
    let said = r.core.tick(T0 + 3 * SEC, timeout, false).unwrap();
    assert!(said.contains("unreachable") && said.contains("no replica yet"), "{said}");
    assert_eq!(r.core.tick(T0 + 4 * SEC, timeout, false), None, "once per silence");
    assert!(applied(r.send(&chunk(1, 1, 1), T0 + 5 * SEC)));
    let said = r.core.tick(T0 + 8 * SEC, timeout, true).unwrap();
    assert!(said.contains("no data from the source") && said.contains("replica in error"), "{said}");
    assert_eq!(r.core.writer().unwrap().state(), State::Error);
    assert_eq!(r.core.st.outages, 1);
    // Data brings it back.
    assert!(applied(r.send(&chunk(1, 1, 1 + u64::from(NFPC)), T0 + 9 * SEC)));
    assert_eq!(r.core.writer().unwrap().state(), State::Capturing);
}

#[test]
fn a_serve_restart_whose_token_went_away_is_followed_after_a_short_silence() {
    let mut r = Rig::new("restart");
    let n = u64::from(NFPC);
    assert!(applied(r.send(&chunk(1, 1, 1), T0)));
    // The new instance too soon: still a second source.
    assert_eq!(r.send(&chunk(2, 1, 1 + n), T0 + 300_000_000), Outcome::OtherSource);
    // The old one's token went away (it exited): 200 ms of silence are enough.
    r.core.on_token(1, false);
    assert_eq!(
        r.send(&chunk(2, 1, 1 + 2 * n), T0 + 400_000_000),
        Outcome::Applied { gap: n, new_replica: false }
    );
    // A forged token removal while the followed stream flows changes nothing.
    r.core.on_token(2, false);
    assert!(applied(r.send(&chunk(2, 1, 1 + 3 * n), T0 + 401_000_000)));
    assert_eq!(r.send(&chunk(3, 1, 1 + 4 * n), T0 + 402_000_000), Outcome::OtherSource);
}

#[test]
fn a_fresh_chunk_after_a_backlog_of_late_ones_is_taken_when_the_clock_says_it_is_due() {
    // A congested link: chunks arrive seconds late in a burst, serve dropped the ones in
    // between, and the next one sent is 4.8 s ahead, arriving right after the backlog.
    let mut r = Rig::new("backlog");
    let n = u64::from(NFPC);
    let offset = Some(ClockMap { offset_ns: -7 * SEC as i64, uncertainty_ns: 0 }); // source clock = local - 7 s
                                                                                   // The last chunk of the backlog (frame `late`) was captured 5 s before it arrived at T0.
    let late = 1 + 10 * n;
    let stamp = |frame: u64| (T0 - 12 * SEC) + (frame - late) * SEC / u64::from(RATE);
    let msg = |frame: u64| {
        let h =
            Header { mono_ns: stamp(frame), send_mono_ns: stamp(frame) + 1_000_000, ..header(1, 1, frame) };
        wire::encode(&h, &signature(1, 1, frame))
    };
    assert!(applied(r.core.on_message(&msg(late), T0, offset)[0]));
    let fresh = (late + 48 * u64::from(RATE) / 10) / n * n + 1; // 4.8 s later
    let o = r.core.on_message(&msg(fresh), T0 + 1_000_000, offset)[0];
    assert!(applied(o), "{o:?}");
    // Without the clock only the arrival times count: refused (2 s margin + a window).
    let mut r2 = Rig::new("backlog2");
    assert!(applied(r2.core.on_message(&msg(late), T0, None)[0]));
    assert_eq!(r2.core.on_message(&msg(fresh), T0 + 1_000_000, None)[0], Outcome::FarFrame);
    // And a chunk at frame ~2^62 is refused with the clock too.
    let far = (bassport::format::MAX_FRAME_INDEX - 2 * n) / n * n + 1;
    assert_eq!(r.core.on_message(&chunk(1, 1, far), T0 + 3_000_000, offset)[0], Outcome::FarFrame);
}

#[test]
fn a_late_chunk_after_a_source_loss_is_late_and_a_discontinuity_in_the_replica() {
    let mut r = Rig::new("late");
    let n = u64::from(NFPC);
    assert!(applied(r.send(&chunk(1, 1, 1), T0)));
    // serve dropped a chunk (SOURCE_LOSS, sequence jump); the next one was LATE at the source.
    let h = Header { flags: wire::flags::SOURCE_LOSS | wire::flags::LATE, ..header(1, 1, 1 + 2 * n) };
    let msg = wire::encode(&h, &signature(1, 1, 1 + 2 * n));
    assert_eq!(r.send(&msg, T0 + 1_000_000), Outcome::Applied { gap: n, new_replica: false });
    let port = Port::open_path(&r.port_path()).unwrap();
    assert_eq!(port.chunk_info(1).unwrap().flags, chunk_flags::TIME_ESTIMATED);
    assert_ne!(port.chunk_info(1 + n).unwrap().flags & chunk_flags::GAP, 0, "the dropped chunk: GAP");
    assert_eq!(
        port.chunk_info(1 + 2 * n).unwrap().flags,
        chunk_flags::LATE | chunk_flags::DISCONTINUITY | chunk_flags::TIME_ESTIMATED
    );
}

#[test]
fn the_status_says_why_the_replica_is_in_error_and_forgets_it_when_data_comes_back() {
    // Before the fix the status file said `"state": "error"` with `"error": null`.
    let mut r = Rig::new("status-error");
    let timeout = 2 * SEC;
    assert!(applied(r.send(&chunk(1, 1, 1), T0)));
    assert!(r.core.tick(T0 + 3 * SEC, timeout, true).is_some());
    r.core.refresh();
    assert_eq!(r.core.st.state, crate::net::BridgeState::Error);
    let err = r.core.st.error.clone().expect("an error text while the state is error");
    assert!(err.contains("no data from the source for more than 2.0 s"), "{err}");
    let file = serde_json::to_value(&r.core.st).unwrap();
    assert_eq!((file["state"].as_str(), file["error"].as_str()), (Some("error"), Some(err.as_str())));
    assert!(applied(r.send(&chunk(1, 1, 1 + u64::from(NFPC)), T0 + 4 * SEC)));
    r.core.refresh();
    assert_eq!((r.core.st.state, r.core.st.error.as_deref()), (crate::net::BridgeState::Capturing, None));
    // A source that reports an error: its message is the mirror's error.
    r.core.on_state(&state("error", "unplugged", 1), T0 + 5 * SEC);
    assert!(r.core.tick(T0 + 5 * SEC + STATE_CONFIRM_NS, timeout, true).is_none());
    r.core.refresh();
    assert_eq!(r.core.st.state, crate::net::BridgeState::Error);
    assert_eq!(r.core.st.error.as_deref(), Some("source: unplugged"));
}

/// Format 2.4 across the network: a replica chunk's bound is the source's plus the clock
/// map's uncertainty, its channel masks are the source's; without a map (arrival-time
/// stamps) or without a source bound, the replica claims none.
#[test]
fn a_replica_chunk_carries_the_source_bound_plus_the_map_uncertainty_and_the_masks() {
    let mut r = Rig::new("bound");
    let n = u64::from(NFPC);
    let map = Some(ClockMap { offset_ns: -7 * SEC as i64, uncertainty_ns: 25_000 });
    let h = |k: u64, bound_ns: u64| Header {
        mono_ns: 5 * SEC + k * SEC / 100,
        bound_ns,
        missing_channels: 0b10,
        unaligned_channels: 0b01,
        ..header(1, 1, 1 + k * n)
    };
    let send = |r: &mut Rig, k: u64, bound: u64, clock: Option<ClockMap>| {
        let msg = wire::encode(&h(k, bound), &signature(1, 1, 1 + k * n));
        assert!(applied(r.core.on_message(&msg, T0 + k, clock)[0]));
    };
    send(&mut r, 0, 40_000, map);
    send(&mut r, 1, 40_000, None);
    send(&mut r, 2, bassport::format::BOUND_UNKNOWN, map);
    let port = Port::open_path(&r.port_path()).unwrap();
    let c = port.chunk_info(1).unwrap();
    assert_eq!((c.mono_ns, c.bound()), (12 * SEC, Some(65_000)));
    assert_eq!((c.missing_channels, c.unaligned_channels), (0b10, 0b01));
    assert_eq!(port.chunk_info(1 + n).unwrap().bound(), None, "no map: arrival-time stamps");
    assert_eq!(port.chunk_info(1 + 2 * n).unwrap().bound(), None, "no source bound");
}
