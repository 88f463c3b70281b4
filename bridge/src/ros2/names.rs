//! rmw_zenoh's names for a ROS 2 graph on Zenoh (ros2/rmw_zenoh, `docs/design.md`, Jazzy):
//! the key expression of a topic's data, the liveliness tokens that make a node and its
//! publishers visible to `ros2 node list` / `ros2 topic list`, their compact QoS text, the
//! entity GID and the attachment every message carries.
//!
//! ```text
//! data      <domain>/<topic without its leading '/'>/<dds type>/<type hash>
//!           0/bass/default/audio/audio_common_msgs::msg::dds_::AudioDataStamped_/RIHS01_6fc6...
//! node      @ros2_lv/<domain>/<zid>/<node id>/<node id>/NN/<enclave>/<namespace>/<node>
//! publisher @ros2_lv/<domain>/<zid>/<node id>/<entity id>/MP/<enclave>/<namespace>/<node>/
//!               <topic>/<dds type>/<type hash>/<qos>
//!           (enclave, namespace and topic "mangled": every '/' becomes '%'; "/" is "%")
//! qos       <reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
//!               <liveliness>,<lease s>,<ns>   each empty where it is rmw_zenoh's default
//!               (RELIABLE, VOLATILE, KEEP_LAST, 42, infinite, infinite, AUTOMATIC, infinite)
//! attachment  sequence number i64 LE | source timestamp i64 LE (ns since the Unix epoch) |
//!             16 (the GID's length, one byte) | GID, 16 bytes           = 33 bytes
//! ```
//!
//! The zid is the session's Zenoh id as Zenoh prints it (lowercase hex). The GID of an entity
//! is XXH3-128 of its liveliness key expression (low 64 bits then high 64 bits, each
//! little-endian), as rmw_zenoh derives it, so a ROS node's graph cache and the attachments
//! name the same publisher. Humble's rmw_zenoh has no type hashes: it writes
//! `TypeHashNotSupported` in their place ([`Distro::Humble`]).

/// Which rmw_zenoh's layout to follow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Distro {
    /// Jazzy and later (Kilted, Rolling): RIHS01 type hashes.
    Jazzy,
    /// Humble: `TypeHashNotSupported` where the type hash goes.
    Humble,
}

/// What Humble's rmw_zenoh writes where a type hash goes.
pub const HUMBLE_TYPE_HASH: &str = "TypeHashNotSupported";

/// Prefix of every liveliness token of a ROS 2 graph.
pub const ADMIN_SPACE: &str = "@ros2_lv";

/// Bytes of an entity GID (rmw's `RMW_GID_STORAGE_SIZE` as rmw_zenoh fills it).
pub const GID_LEN: usize = 16;

/// Bytes of a message's attachment.
pub const ATTACHMENT_LEN: usize = 8 + 8 + 1 + GID_LEN;

/// The domain id from `ROS_DOMAIN_ID`'s value (`None` or empty: 0, as rcl reads it).
pub fn domain_id(var: Option<&str>) -> Result<u32, String> {
    match var.map(str::trim) {
        None | Some("") => Ok(0),
        Some(v) => {
            v.parse::<u32>().map_err(|_| format!("ROS_DOMAIN_ID={v:?} is not a domain id (0, 1, ...)"))
        }
    }
}

/// `pkg/msg/Type` as DDS (and rmw_zenoh) name it: `pkg::msg::dds_::Type_`.
pub fn dds_type_name(ros_type: &str) -> String {
    match ros_type.rsplit_once('/') {
        Some((pkg_msg, t)) => format!("{}::dds_::{t}_", pkg_msg.replace('/', "::")),
        None => format!("{ros_type}_"),
    }
}

/// Checks a fully qualified ROS 2 name (`/a/b_c`): a leading '/', tokens of letters, digits
/// and '_' not starting with a digit, no empty token, no trailing '/', no "__".
pub fn check_name(name: &str) -> Result<(), String> {
    let bad = |why: &str| Err(format!("{name:?} is not a ROS 2 topic name: {why}"));
    let Some(rest) = name.strip_prefix('/') else { return bad("it must start with '/'") };
    if rest.is_empty() {
        return bad("it has no name after '/'");
    }
    if name.contains("__") {
        return bad("\"__\" is reserved");
    }
    for token in rest.split('/') {
        if token.is_empty() {
            return bad("empty token (\"//\" or a trailing '/')");
        }
        if !token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return bad("only letters, digits and '_' between the '/'");
        }
        if token.starts_with(|c: char| c.is_ascii_digit()) {
            return bad("a token starts with a digit");
        }
    }
    Ok(())
}

/// Checks a node name: letters, digits and '_', not starting with a digit.
pub fn check_node_name(name: &str) -> Result<(), String> {
    let ok = !name.is_empty()
        && !name.starts_with(|c: char| c.is_ascii_digit())
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    if ok {
        Ok(())
    } else {
        Err(format!("{name:?} is not a ROS 2 node name (letters, digits and '_', not starting with a digit)"))
    }
}

/// Every '/' as '%' (rmw_zenoh's mangling of names inside a liveliness token).
pub fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// The key expression of a topic's data:
///
/// ```
/// use bass_bridge::ros2::names::{dds_type_name, topic_key};
/// let ty = dds_type_name("audio_common_msgs/msg/AudioInfo");
/// assert_eq!(topic_key(0, "/bass/default/audio_info", &ty, "RIHS01_b349"),
///            "0/bass/default/audio_info/audio_common_msgs::msg::dds_::AudioInfo_/RIHS01_b349");
/// ```
pub fn topic_key(domain: u32, topic: &str, dds_type: &str, type_hash: &str) -> String {
    format!("{domain}/{}/{dds_type}/{type_hash}", topic.trim_matches('/'))
}

/// A publisher's QoS, as far as bass sets it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Qos {
    /// RELIABLE (true) or BEST_EFFORT.
    pub reliable: bool,
    /// TRANSIENT_LOCAL (true: late subscribers get the last `depth` messages) or VOLATILE.
    pub transient_local: bool,
    /// KEEP_LAST depth.
    pub depth: u32,
}

impl Qos {
    /// rmw_zenoh's default depth, left out of the text.
    const DEFAULT_DEPTH: u32 = 42;

    /// The compact text of a liveliness token (see the module's comment). rmw's enums:
    /// reliability RELIABLE 1, BEST_EFFORT 2; durability TRANSIENT_LOCAL 1, VOLATILE 2.
    pub fn key(&self) -> String {
        let reliability = if self.reliable { "" } else { "2" };
        let durability = if self.transient_local { "1" } else { "" };
        let depth = if self.depth == Self::DEFAULT_DEPTH { String::new() } else { self.depth.to_string() };
        format!("{reliability}:{durability}:,{depth}:,:,:,,")
    }
}

/// The kind of a graph entity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// `NN`.
    Node,
    /// `MP`.
    Publisher,
}

/// A topic as a publisher's token names it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TopicInfo {
    /// Fully qualified name (`/bass/default/audio`).
    pub name: String,
    /// DDS type name ([`dds_type_name`]).
    pub dds_type: String,
    /// `RIHS01_...` or [`HUMBLE_TYPE_HASH`].
    pub type_hash: String,
    /// QoS.
    pub qos: Qos,
}

/// One entity of the graph: a node or one of its publishers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Entity {
    /// ROS domain id.
    pub domain: u32,
    /// The Zenoh session's id, as Zenoh prints it.
    pub zid: String,
    /// Id of the node within the session.
    pub node_id: u64,
    /// Id of the entity (the node's own for a node).
    pub entity_id: u64,
    /// Node or publisher.
    pub kind: Kind,
    /// Node namespace (`/`).
    pub namespace: String,
    /// Node name.
    pub node: String,
    /// The topic of a publisher.
    pub topic: Option<TopicInfo>,
}

impl Entity {
    /// The entity's liveliness token key expression.
    pub fn token(&self) -> String {
        let kind = match self.kind {
            Kind::Node => "NN",
            Kind::Publisher => "MP",
        };
        // The SROS enclave is "/" (none), mangled to "%".
        let mut k = format!(
            "{ADMIN_SPACE}/{}/{}/{}/{}/{kind}/%/{}/{}",
            self.domain,
            self.zid,
            self.node_id,
            self.entity_id,
            mangle(&self.namespace),
            mangle(&self.node)
        );
        if let Some(t) = &self.topic {
            k.push_str(&format!(
                "/{}/{}/{}/{}",
                mangle(&t.name),
                mangle(&t.dds_type),
                t.type_hash,
                t.qos.key()
            ));
        }
        k
    }

    /// The entity's GID: XXH3-128 of its token (see the module's comment).
    pub fn gid(&self) -> [u8; GID_LEN] {
        let h = xxhash_rust::xxh3::xxh3_128(self.token().as_bytes());
        let mut g = [0; GID_LEN];
        g[..8].copy_from_slice(&(h as u64).to_le_bytes());
        g[8..].copy_from_slice(&((h >> 64) as u64).to_le_bytes());
        g
    }
}

/// The attachment of a message: sequence number, source timestamp, publisher GID.
pub fn attachment(sequence: i64, source_timestamp_ns: i64, gid: &[u8; GID_LEN]) -> [u8; ATTACHMENT_LEN] {
    let mut a = [0; ATTACHMENT_LEN];
    a[..8].copy_from_slice(&sequence.to_le_bytes());
    a[8..16].copy_from_slice(&source_timestamp_ns.to_le_bytes());
    a[16] = GID_LEN as u8;
    a[17..].copy_from_slice(gid);
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_and_tokens_follow_rmw_zenohs_documented_examples() {
        // rmw_zenoh docs/design.md: the talker's publisher on chatter (depth 7), domain 2.
        let zid = "8b20917502ee955ac4476e0266340d5c";
        let hash = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18";
        let dds = dds_type_name("std_msgs/msg/String");
        assert_eq!(dds, "std_msgs::msg::dds_::String_");
        assert_eq!(topic_key(0, "/chatter", &dds, hash), format!("0/chatter/{dds}/{hash}"));
        assert_eq!(topic_key(0, "/robot1/chatter", &dds, hash), format!("0/robot1/chatter/{dds}/{hash}"));
        let qos = Qos { reliable: true, transient_local: false, depth: 7 };
        let pubr = Entity {
            domain: 2,
            zid: zid.into(),
            node_id: 0,
            entity_id: 10,
            kind: Kind::Publisher,
            namespace: "/".into(),
            node: "talker".into(),
            topic: Some(TopicInfo { name: "/chatter".into(), dds_type: dds, type_hash: hash.into(), qos }),
        };
        assert_eq!(
            pubr.token(),
            format!("@ros2_lv/2/{zid}/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/{hash}/::,7:,:,:,,")
        );
        let node =
            Entity { entity_id: 0, kind: Kind::Node, topic: None, node: "listener".into(), ..pubr.clone() };
        assert_eq!(node.token(), format!("@ros2_lv/2/{zid}/0/0/NN/%/%/listener"));
    }

    #[test]
    fn qos_text_leaves_rmw_zenohs_defaults_empty() {
        assert_eq!(Qos { reliable: true, transient_local: false, depth: 42 }.key(), "::,:,:,:,,");
        assert_eq!(Qos { reliable: true, transient_local: true, depth: 1 }.key(), ":1:,1:,:,:,,");
        assert_eq!(Qos { reliable: false, transient_local: false, depth: 10 }.key(), "2::,10:,:,:,,");
    }

    #[test]
    fn names_are_checked_as_ros_checks_them() {
        for ok in ["/bass/default/audio", "/a", "/a_b/c9"] {
            assert_eq!(check_name(ok), Ok(()), "{ok}");
        }
        for bad in ["bass/audio", "/", "/a//b", "/a/", "/a-b", "/9a", "/a__b", "/a/b c"] {
            assert!(check_name(bad).is_err(), "{bad}");
        }
        assert!(check_node_name("bass_bridge_default").is_ok());
        assert!(check_node_name("bass-bridge").is_err() && check_node_name("1x").is_err());
        assert_eq!(domain_id(None), Ok(0));
        assert_eq!(domain_id(Some("")), Ok(0));
        assert_eq!(domain_id(Some("42")), Ok(42));
        assert!(domain_id(Some("-1")).is_err() && domain_id(Some("x")).is_err());
    }

    #[test]
    fn the_attachment_has_rmw_zenohs_33_bytes() {
        let gid: [u8; 16] = std::array::from_fn(|i| i as u8 + 1);
        let a = attachment(7, 1_700_000_000_000_000_001, &gid);
        assert_eq!(a.len(), 33);
        assert_eq!(a[..8], 7i64.to_le_bytes());
        assert_eq!(a[8..16], 1_700_000_000_000_000_001i64.to_le_bytes());
        assert_eq!((a[16], &a[17..]), (16, &gid[..]));
    }

    #[test]
    fn the_gid_is_xxh3_128_of_the_token() {
        // XXH3-128 of the empty input (xxHash's reference value), as rmw_zenoh's copy computes it.
        let h = xxhash_rust::xxh3::xxh3_128(b"");
        assert_eq!(h, 0x99aa06d3014798d86001c324468d497f);
        let e = Entity {
            domain: 0,
            zid: "1".into(),
            node_id: 0,
            entity_id: 0,
            kind: Kind::Node,
            namespace: "/".into(),
            node: "n".into(),
            topic: None,
        };
        let g = e.gid();
        let h = xxhash_rust::xxh3::xxh3_128(e.token().as_bytes());
        assert_eq!(u128::from(u64::from_le_bytes(g[..8].try_into().unwrap())), h & u128::from(u64::MAX));
        assert_eq!(u128::from(u64::from_le_bytes(g[8..].try_into().unwrap())), h >> 64);
        assert_ne!(Entity { entity_id: 1, ..e.clone() }.gid(), g);
    }
}
