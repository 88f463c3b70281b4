//! `serve --ros2`: the port as ROS 2 topics, laid out on Zenoh exactly as rmw_zenoh (the ROS 2
//! middleware on Zenoh, Jazzy) lays out a node's publishers, so that ROS 2 nodes using
//! `rmw_zenoh_cpp` see a node `bass_bridge_<broker>` and subscribe to its topics with no ROS
//! installation on the robot (docs/ros2.md):
//!
//! - `/bass/<broker>/audio` ([`basskit::ros2::AUDIO_DATA_STAMPED`]): one message per chunk,
//!   interleaved S32LE samples, `header.stamp` the CLOCK_REALTIME of its first frame;
//!   RELIABLE, VOLATILE, KEEP_LAST 10;
//! - `/bass/<broker>/audio_info` (`AudioInfo`): once per acquisition, TRANSIENT_LOCAL depth 1
//!   (a "latched" topic: an advanced publisher whose last message late subscribers query,
//!   answered at a bounded rate by [`latched`]);
//! - `/bass/<broker>/chunk_info` (`bass_msgs/msg/ChunkInfo`): per audio message, with the
//!   same stamp, its first frame index, frames, the port's chunk flags and `lost_before`, the
//!   frames of this acquisition that serve did not publish since the previous message (queue
//!   full, port lapped, GAP chunks: never zeros presented as audio).
//!
//! The names, tokens and attachment are [`names`]; the type hashes [`typehash`]; the CDR
//! payloads [`basskit::ros2`]. The port reader hands each chunk to [`Exporter::offer`],
//! which never waits for the network (except, bounded, for a new port's backlog, as serve's
//! own chunks do): a thread of its own encodes and puts.

pub mod latched;
pub mod names;
pub mod typehash;

use std::sync::atomic::AtomicBool;
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{anyhow, Context, Result};
use basskit::ros2::{self as msgs, AudioDataStamped, AudioInfo, ChunkInfo, Header, Time, Topics};
use zenoh::Wait;
use zenoh_ext::{AdvancedPublisherBuilderExt, MissDetectionConfig};

use crate::usage::UsageError;
use crate::wire;
use names::{Distro, Entity, Kind, Qos, TopicInfo};

/// Options of `serve` for the ROS 2 topics.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct Ros2Opts {
    /// Also publish the port as ROS 2 topics the way rmw_zenoh does (domain from
    /// ROS_DOMAIN_ID; docs/ros2.md).
    #[arg(long)]
    pub ros2: bool,
    /// The audio topic (default /bass/<broker>/audio); AudioInfo goes on <TOPIC>_info and the
    /// ChunkInfo on chunk_info beside it.
    #[arg(long, value_name = "TOPIC", requires = "ros2")]
    pub ros2_topic: Option<String>,
    /// Node name (default bass_bridge_<broker>).
    #[arg(long, value_name = "NAME", requires = "ros2")]
    pub ros2_node: Option<String>,
    /// header.frame_id of the messages (default empty).
    #[arg(long, value_name = "ID", requires = "ros2")]
    pub ros2_frame_id: Option<String>,
    /// rmw_zenoh's layout to follow: jazzy (also Kilted, Rolling) or humble (default jazzy).
    #[arg(long, value_enum, value_name = "DISTRO", requires = "ros2")]
    pub ros2_distro: Option<Distro>,
}

/// The topics of these options for `broker`, checked.
pub fn topics(o: &Ros2Opts, broker: &str) -> Result<Topics, UsageError> {
    let t = match &o.ros2_topic {
        None => Topics::of(broker),
        Some(audio) => {
            names::check_name(audio).map_err(|e| UsageError(format!("--ros2-topic: {e}")))?;
            let parent = audio.rsplit_once('/').map_or("", |(p, _)| p);
            Topics {
                audio: audio.clone(),
                info: format!("{audio}_info"),
                chunks: format!("{parent}/chunk_info"),
            }
        }
    };
    for n in [&t.audio, &t.info, &t.chunks] {
        names::check_name(n).map_err(|e| UsageError(format!("--ros2-topic: {e}")))?;
    }
    Ok(t)
}

/// The node name of these options for `broker`.
pub fn node_name(o: &Ros2Opts, broker: &str) -> Result<String, UsageError> {
    let n = o.ros2_node.clone().unwrap_or_else(|| format!("bass_bridge_{}", msgs::name_token(broker)));
    names::check_node_name(&n).map_err(|e| UsageError(format!("--ros2-node: {e}")))?;
    Ok(n)
}

/// The key expressions of these options' topics that only serve may put, reply or declare
/// queryables and tokens on ([`crate::net::Role::Serve`]): each topic's data keys (any type and
/// hash), the history queryables and tokens of its advanced publishers, and its publishers'
/// liveliness tokens in the ROS graph.
pub fn guarded_keys(o: &Ros2Opts, broker: &str) -> Result<Vec<String>, UsageError> {
    let domain = check(o, broker)?;
    let t = topics(o, broker)?;
    let mut keys = Vec::new();
    for topic in [&t.audio, &t.info, &t.chunks] {
        // `**` matches no `@adv` chunk: the advanced publisher's keys are named apart.
        keys.push(format!("{domain}/{}/**", topic.trim_matches('/')));
        keys.push(format!("{}/@adv/pub/**", names::topic_key(domain, topic, "*", "*")));
        keys.push(format!("{}/{domain}/*/*/*/MP/*/*/*/{}/**", names::ADMIN_SPACE, names::mangle(topic)));
    }
    Ok(keys)
}

/// Checks the options (topics, node name, `ROS_DOMAIN_ID`) before anything is opened.
pub fn check(o: &Ros2Opts, broker: &str) -> Result<u32, UsageError> {
    topics(o, broker)?;
    node_name(o, broker)?;
    names::domain_id(std::env::var("ROS_DOMAIN_ID").ok().as_deref()).map_err(UsageError)
}

/// Chunks queued in front of the ROS thread (at least; `--queue` when larger). Deeper than
/// serve's own queue: a ROS thread descheduled for a few chunk periods on a busy machine should
/// not cost ROS subscribers audio, and nothing downstream waits on this queue's depth.
pub const QUEUE: usize = 16;

/// Depth of the audio and chunk_info publishers (rclcpp's usual `QoS(10)`).
pub const DEPTH: u32 = 10;

/// One topic's publisher, its GID and the entity behind its token.
struct Publisher {
    zenoh: Zpub,
    gid: [u8; names::GID_LEN],
    key: String,
    /// The history of a TRANSIENT_LOCAL publisher.
    latched: Option<latched::Latched>,
}

enum Zpub {
    Plain(zenoh::pubsub::Publisher<'static>),
    Advanced(zenoh_ext::AdvancedPublisher<'static>),
}

impl Publisher {
    /// Puts `payload` with the attachment of message `sequence` (rmw_zenoh numbers from 1).
    fn put(&mut self, payload: &[u8], sequence: i64) {
        let now = i64::try_from(bassport::sys::realtime_ns()).unwrap_or(i64::MAX);
        let att = names::attachment(sequence, now, &self.gid).to_vec();
        if let Some(l) = self.latched.as_mut() {
            l.record(payload, &att);
        }
        let r = match &self.zenoh {
            Zpub::Plain(p) => p.put(payload.to_vec()).attachment(att).wait(),
            Zpub::Advanced(p) => p.put(payload.to_vec()).attachment(att).wait(),
        };
        if let Err(e) = r {
            tracing::warn!("ROS 2 put on {}: {e}", self.key);
        }
    }
}

/// The graph entities of `serve --ros2`: the node's and its publishers' liveliness tokens,
/// kept until serve ends (dropping them takes the node off every ROS graph).
pub struct Graph {
    _tokens: Vec<zenoh::liveliness::LivelinessToken>,
}

/// A chunk on its way to the ROS thread.
struct Item {
    epoch: u64,
    first_frame: u64,
    frames: u32,
    channels: usize,
    flags: u32,
    mono_ns: u64,
    realtime_ns: u64,
    lost_before: u64,
    /// The port row's bound ([`msgs::BOUND_UNKNOWN`] = not known) and channel masks.
    ext: [u64; 3],
    sequence: i64,
    planar: Vec<i32>,
}

/// The port reader's side of the ROS 2 export (see the module's comment).
pub struct Exporter {
    tx: SyncSender<Item>,
    free: Receiver<Vec<i32>>,
    info: Arc<Mutex<Option<AudioInfo>>>,
    /// (epoch, channels, rate) of the last chunk offered.
    stream: Option<(u64, u16, u32)>,
    /// The frame after the last chunk handed to the ROS thread.
    next_frame: u64,
    /// The next message's sequence number (audio and chunk_info count alike).
    sequence: i64,
    /// Messages not published (queue full), counted.
    pub dropped: u64,
    thread: std::thread::JoinHandle<()>,
}

/// Declares the node, its three publishers and their tokens on `session`, and starts the
/// thread that publishes; returns the graph (keep it) and the exporter for the port reader.
pub fn start(
    session: &zenoh::Session,
    o: &Ros2Opts,
    broker: &str,
    queue: usize,
) -> Result<(Graph, Exporter)> {
    let domain = check(o, broker)?;
    let topics = topics(o, broker)?;
    let node = node_name(o, broker)?;
    let distro = o.ros2_distro.unwrap_or(Distro::Jazzy);
    let frame_id = o.ros2_frame_id.clone().unwrap_or_default();
    let zid = session.zid().to_string();
    let node_entity = Entity {
        domain,
        zid: zid.clone(),
        node_id: 0,
        entity_id: 0,
        kind: Kind::Node,
        namespace: "/".into(),
        node: node.clone(),
        topic: None,
    };
    let mut tokens = vec![declare_token(session, &node_entity.token())?];
    let volatile = Qos { reliable: true, transient_local: false, depth: DEPTH };
    let latched = Qos { reliable: true, transient_local: true, depth: 1 };
    let mut make = |id: u64, topic: &str, ty: &str, def: &str, qos: Qos| -> Result<Publisher> {
        let hash = match distro {
            Distro::Jazzy => typehash::rihs01(ty, def).with_context(|| format!("type hash of {ty}"))?,
            Distro::Humble => names::HUMBLE_TYPE_HASH.to_string(),
        };
        let info = TopicInfo { name: topic.into(), dds_type: names::dds_type_name(ty), type_hash: hash, qos };
        let key = names::topic_key(domain, topic, &info.dds_type, &info.type_hash);
        let entity =
            Entity { entity_id: id, kind: Kind::Publisher, topic: Some(info), ..node_entity.clone() };
        let builder = session
            .declare_publisher(key.clone())
            .congestion_control(zenoh::qos::CongestionControl::Drop)
            .reliability(zenoh::qos::Reliability::Reliable);
        let (zenoh, latched) = if qos.transient_local {
            // As rmw_zenoh: the last message for late subscribers and detection of this
            // publisher (our own queryable and token, where zenoh-ext's cache and
            // publisher_detection would be: [`latched`]), and sporadic heartbeats for
            // RELIABLE + TRANSIENT_LOCAL. Depth 1 only.
            debug_assert_eq!(qos.depth, 1);
            let p = builder
                .sample_miss_detection(
                    MissDetectionConfig::default().sporadic_heartbeat(Duration::from_millis(500)),
                )
                .wait()
                .map_err(|e| anyhow!("declare the ROS 2 publisher {key}: {e}"))?;
            let l = latched::Latched::declare(session, &key, &p)?;
            (Zpub::Advanced(p), Some(l))
        } else {
            (
                Zpub::Plain(builder.wait().map_err(|e| anyhow!("declare the ROS 2 publisher {key}: {e}"))?),
                None,
            )
        };
        tokens.push(declare_token(session, &entity.token())?);
        tracing::info!(topic, key = %key, "ROS 2 publisher");
        Ok(Publisher { zenoh, gid: entity.gid(), key, latched })
    };
    let audio =
        make(1, &topics.audio, msgs::AUDIO_DATA_STAMPED, msgs::AUDIO_DATA_STAMPED_DEFINITION, volatile)?;
    let info = make(2, &topics.info, msgs::AUDIO_INFO, msgs::AUDIO_INFO_DEFINITION, latched)?;
    let chunks = make(3, &topics.chunks, msgs::CHUNK_INFO, msgs::CHUNK_INFO_DEFINITION, volatile)?;
    tracing::info!(node = %node, domain, distro = ?distro, "ROS 2 node (rmw_zenoh layout)");

    let (tx, rx) = sync_channel::<Item>(queue);
    let (free_tx, free) = sync_channel::<Vec<i32>>(queue + 2);
    let pending_info = Arc::new(Mutex::new(None));
    let p = pending_info.clone();
    let thread = std::thread::Builder::new().name("bridge-ros2".into()).spawn(move || {
        publish_loop(rx, free_tx, p, [audio, info, chunks], frame_id);
    })?;
    let exporter = Exporter {
        tx,
        free,
        info: pending_info,
        stream: None,
        next_frame: 0,
        sequence: 1,
        dropped: 0,
        thread,
    };
    Ok((Graph { _tokens: tokens }, exporter))
}

fn declare_token(session: &zenoh::Session, key: &str) -> Result<zenoh::liveliness::LivelinessToken> {
    session
        .liveliness()
        .declare_token(key.to_string())
        .wait()
        .map_err(|e| anyhow!("liveliness token {key}: {e}"))
}

/// The ROS thread: AudioInfo when a new acquisition starts, then each chunk as an audio
/// message and its ChunkInfo.
fn publish_loop(
    rx: Receiver<Item>,
    free: SyncSender<Vec<i32>>,
    info: Arc<Mutex<Option<AudioInfo>>>,
    [mut audio, mut info_pub, mut chunks]: [Publisher; 3],
    frame_id: String,
) {
    let (mut interleaved, mut bytes) = (Vec::new(), Vec::new());
    let mut info_sequence = 1;
    for it in rx {
        if let Some(i) = info.lock().unwrap_or_else(|e| e.into_inner()).take() {
            i.encode(&mut bytes);
            info_pub.put(&bytes, info_sequence);
            info_sequence += 1;
        }
        let frames = it.frames as usize;
        interleaved.resize(it.planar.len(), 0);
        for (i, s) in interleaved.iter_mut().enumerate() {
            *s = it.planar[(i % it.channels) * frames + i / it.channels];
        }
        let header = Header { stamp: Time::from_ns(it.realtime_ns), frame_id: frame_id.clone() };
        AudioDataStamped::encode_samples(&header, &interleaved, &mut bytes);
        audio.put(&bytes, it.sequence);
        ChunkInfo {
            header,
            epoch: it.epoch,
            first_frame: it.first_frame,
            frames: it.frames,
            chunk_first_frame: it.first_frame,
            chunk_frames: it.frames,
            flags: it.flags,
            monotonic_ns: it.mono_ns,
            realtime_ns: it.realtime_ns,
            lost_before: it.lost_before,
            bound_ns: it.ext[0],
            missing_channels: it.ext[1],
            unaligned_channels: it.ext[2],
        }
        .encode(&mut bytes);
        chunks.put(&bytes, it.sequence);
        let _ = free.try_send(it.planar);
    }
}

impl Exporter {
    /// Hands one chunk (header `h`, samples planar as in the port) to the ROS thread. A GAP
    /// chunk is not published (its frames count in the next message's `lost_before`); a full
    /// queue drops the chunk, counted, once `may_wait()` says so (serve's reader: live, once
    /// the chunk fell [`crate::patience::LIVE_PATIENCE`] behind the port; a new port's
    /// backlog, after [`crate::patience::CATCH_UP_PATIENCE`]) or `term` is set.
    pub fn offer(
        &mut self,
        h: &wire::Header,
        planar: &[i32],
        term: &AtomicBool,
        may_wait: impl FnMut() -> bool,
    ) {
        if h.flags & wire::flags::GAP != 0 {
            return;
        }
        let stream = (h.epoch, h.channels, h.sample_rate);
        if self.stream != Some(stream) {
            // A new acquisition: its AudioInfo goes first; its first message has no loss before.
            *self.info.lock().unwrap_or_else(|e| e.into_inner()) =
                Some(AudioInfo::s32le(h.channels.min(255) as u8, h.sample_rate));
            self.stream = Some(stream);
            self.next_frame = h.first_frame;
        }
        let mut buf = self.free.try_recv().unwrap_or_default();
        buf.clear();
        buf.extend_from_slice(planar);
        let item = Item {
            epoch: h.epoch,
            first_frame: h.first_frame,
            frames: h.frames,
            channels: usize::from(h.channels.max(1)),
            flags: h.flags & wire::flags::PORT,
            mono_ns: h.mono_ns,
            realtime_ns: h.realtime_ns,
            lost_before: h.first_frame.saturating_sub(self.next_frame),
            ext: [h.bound_ns, h.missing_channels, h.unaligned_channels],
            sequence: self.sequence,
            planar: buf,
        };
        // A dropped message keeps its number: ROS subscribers see the gap (MESSAGE_LOST).
        self.sequence += 1;
        match crate::patience::send_or_give_back(&self.tx, item, term, may_wait) {
            Ok(()) => self.next_frame = h.first_frame + u64::from(h.frames),
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.dropped += 1;
                if self.dropped.is_power_of_two() {
                    tracing::warn!(
                        dropped = self.dropped,
                        "ROS 2 export: queue full, message dropped (counted in the next lost_before)"
                    );
                }
            }
        }
    }

    /// Ends the ROS thread; whether it ended within `patience` (a put may block on a dead link).
    pub fn finish(self, patience: Duration) -> bool {
        let Exporter { tx, thread, .. } = self;
        drop(tx);
        crate::patience::wait_until_finished(&thread, patience)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_follow_the_audio_topic() {
        let o = Ros2Opts { ros2: true, ..Default::default() };
        let t = topics(&o, "left-ear").unwrap();
        assert_eq!(
            (t.audio.as_str(), t.info.as_str(), t.chunks.as_str()),
            ("/bass/left_ear/audio", "/bass/left_ear/audio_info", "/bass/left_ear/chunk_info")
        );
        let o = Ros2Opts { ros2_topic: Some("/robot/mic/audio".into()), ..o };
        let t = topics(&o, "x").unwrap();
        assert_eq!((t.info.as_str(), t.chunks.as_str()), ("/robot/mic/audio_info", "/robot/mic/chunk_info"));
        for bad in ["robot/mic", "/robot/mic/", "/a-b"] {
            assert!(topics(&Ros2Opts { ros2_topic: Some(bad.into()), ..o.clone() }, "x").is_err(), "{bad}");
        }
        assert_eq!(node_name(&Ros2Opts::default(), "left-ear").unwrap(), "bass_bridge_left_ear");
        assert!(node_name(&Ros2Opts { ros2_node: Some("a-b".into()), ..Default::default() }, "x").is_err());
    }

    #[test]
    fn serve_guards_every_key_of_its_topics() {
        let o = Ros2Opts { ros2: true, ..Default::default() };
        let keys = guarded_keys(&o, "src").unwrap();
        let data =
            |t: &str| names::topic_key(0, t, "audio_common_msgs::msg::dds_::AudioInfo_", "RIHS01_b349");
        let covered = |k: &str| {
            let k = zenoh::key_expr::KeyExpr::try_from(k.to_string()).unwrap();
            keys.iter().any(|g| zenoh::key_expr::KeyExpr::try_from(g.clone()).unwrap().includes(&k))
        };
        for t in ["/bass/src/audio", "/bass/src/audio_info", "/bass/src/chunk_info"] {
            assert!(covered(&data(t)), "{t}");
            assert!(covered(&format!("{}/@adv/pub/1f/7/_", data(t))), "{t}: history queryable");
            assert!(
                covered(&format!("@ros2_lv/0/1f/0/3/MP/%/%/n/{}/x/y/::,10:,:,:,,", names::mangle(t))),
                "{t}: token"
            );
        }
        assert!(!covered(&data("/bass/src/audio_extra")) && !covered(&data("/chatter")));
        assert!(
            !covered(&format!("{}/@adv/sub/1f/7/_", data("/bass/src/audio"))),
            "a subscriber's own token"
        );
    }
}
