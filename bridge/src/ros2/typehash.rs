//! The RIHS01 type hash of a ROS 2 message (REP-2011 "type description"), computed from its
//! `ros2msg` definition text ([`basskit::ros2`]'s definitions, the form rosbag2 stores).
//!
//! The hash is SHA-256 over one JSON text of the type's description:
//!
//! ```text
//! {"type_description": {"type_name": "pkg/msg/T", "fields": [FIELD, ...]},
//!  "referenced_type_descriptions": [{"type_name": ..., "fields": [...]}, ...]}   (sorted by name)
//! FIELD = {"name": "x", "type": {"type_id": N, "capacity": N, "string_capacity": N,
//!                                "nested_type_name": "pkg/msg/U" or ""}}
//! ```
//!
//! written as Python's `json.dumps` writes it by default (`", "` and `": "` between items, no
//! other white space), every nested type once, constants, comments and default values left
//! out. The type ids are those of `type_description_interfaces/msg/FieldType`: the primitive's
//! id, +48 for a fixed array, +96 for a bounded sequence, +144 for an unbounded one; a nested
//! type is 1. As `rosidl` turns `.msg` into IDL first, a `char` field is `uint8` (3) and
//! `byte` is `octet` (16). The result is written `RIHS01_` and 64 lowercase hex digits.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use sha2::{Digest, Sha256};

/// Why a definition could not be hashed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TypeHashError {
    /// A line that is neither a field, a constant nor a comment.
    #[error("{type_name}: cannot read the line {line:?}")]
    Line {
        /// The type being read.
        type_name: String,
        /// The line.
        line: String,
    },
    /// A nested type whose definition is not in the text.
    #[error("{0}: its definition is not in the text")]
    Missing(String),
    /// A type name that is not `pkg/Type` or `pkg/msg/Type`.
    #[error("{0:?} is not a message type name")]
    Name(String),
}

/// One field of a type description.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Field {
    name: String,
    type_id: u32,
    capacity: u64,
    string_capacity: u64,
    nested: String,
}

/// `pkg/Type` or `pkg/msg/Type` as `pkg/msg/Type`.
fn full_name(name: &str) -> Result<String, TypeHashError> {
    let ok = |s: &str| !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    // A message type's own name is CamelCase: `float33` is a misspelt primitive, not a type.
    let ty = |s: &str| ok(s) && s.starts_with(|c: char| c.is_ascii_uppercase());
    let parts: Vec<&str> = name.split('/').collect();
    match parts[..] {
        [p, t] if ok(p) && ty(t) => Ok(format!("{p}/msg/{t}")),
        [p, "msg", t] if ok(p) && ty(t) => Ok(name.to_string()),
        _ => Err(TypeHashError::Name(name.to_string())),
    }
}

/// The `type_description_interfaces/msg/FieldType` id of a primitive type, if it is one.
fn primitive_id(t: &str) -> Option<u32> {
    Some(match t {
        "int8" => 2,
        "uint8" | "char" => 3,
        "int16" => 4,
        "uint16" => 5,
        "int32" => 6,
        "uint32" => 7,
        "int64" => 8,
        "uint64" => 9,
        "float32" => 10,
        "float64" => 11,
        "bool" => 15,
        "byte" => 16,
        "string" => 17,
        "wstring" => 18,
        _ => return None,
    })
}

/// Reads one field's type (`uint8[]`, `string<=8[4]`, `std_msgs/Header`, ...) in `package`.
fn field_type(t: &str, package: &str) -> Option<(u32, u64, u64, String)> {
    let (base, offset, capacity) = match t.find('[') {
        None => (t, 0, 0),
        Some(i) => {
            let inner = t[i + 1..].strip_suffix(']')?;
            if inner.is_empty() {
                (&t[..i], 144, 0)
            } else if let Some(n) = inner.strip_prefix("<=") {
                (&t[..i], 96, n.parse().ok()?)
            } else {
                (&t[..i], 48, inner.parse().ok()?)
            }
        }
    };
    for (s, bounded) in [("string<=", 21), ("wstring<=", 22)] {
        if let Some(n) = base.strip_prefix(s) {
            return Some((bounded + offset, capacity, n.parse().ok()?, String::new()));
        }
    }
    if let Some(id) = primitive_id(base) {
        return Some((id + offset, capacity, 0, String::new()));
    }
    let nested = match base {
        "Header" => "std_msgs/msg/Header".to_string(),
        b if b.contains('/') => full_name(b).ok()?,
        b => full_name(&format!("{package}/{b}")).ok()?,
    };
    Some((1 + offset, capacity, 0, nested))
}

/// The fields of one type's text (its own section of a definition).
fn parse_fields(type_name: &str, text: &str) -> Result<Vec<Field>, TypeHashError> {
    let package = type_name.split('/').next().unwrap_or_default();
    let bad = |line: &str| TypeHashError::Line { type_name: type_name.into(), line: line.into() };
    let mut fields = Vec::new();
    for raw in text.lines() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut words = line.split_whitespace();
        let (Some(t), Some(name)) = (words.next(), words.next()) else { return Err(bad(raw)) };
        // A constant (`uint32 GAP=1`, `string S = "a#b"`): not part of the description.
        if name.contains('=') || words.next().is_some_and(|w| w.starts_with('=')) {
            continue;
        }
        let name_ok = name.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        let (type_id, capacity, string_capacity, nested) =
            field_type(t, package).filter(|_| name_ok).ok_or_else(|| bad(raw))?;
        fields.push(Field { name: name.into(), type_id, capacity, string_capacity, nested });
    }
    if fields.is_empty() {
        // rosidl gives an empty message one placeholder member.
        fields.push(Field {
            name: "structure_needs_at_least_one_member".into(),
            type_id: 3,
            capacity: 0,
            string_capacity: 0,
            nested: String::new(),
        });
    }
    Ok(fields)
}

/// Splits a `ros2msg` definition into its types' texts: the main type's first, then each
/// `MSG: pkg/Type` section after a line of `=`.
fn sections(type_name: &str, definition: &str) -> Result<BTreeMap<String, String>, TypeHashError> {
    let mut out = BTreeMap::new();
    let mut name = full_name(type_name)?;
    let mut text = String::new();
    let mut lines = definition.lines().peekable();
    while let Some(line) = lines.next() {
        let rule = line.len() >= 3 && line.chars().all(|c| c == '=');
        match (rule, lines.peek().and_then(|l| l.strip_prefix("MSG: "))) {
            (true, Some(next)) => {
                out.insert(std::mem::replace(&mut name, full_name(next.trim())?), std::mem::take(&mut text));
                lines.next();
            }
            _ => {
                text.push_str(line);
                text.push('\n');
            }
        }
    }
    out.insert(name, text);
    Ok(out)
}

fn write_struct(json: &mut String, name: &str, fields: &[Field]) {
    let _ = write!(json, "{{\"type_name\": \"{name}\", \"fields\": [");
    for (i, f) in fields.iter().enumerate() {
        let sep = if i == 0 { "" } else { ", " };
        let _ = write!(
            json,
            "{sep}{{\"name\": \"{}\", \"type\": {{\"type_id\": {}, \"capacity\": {}, \
             \"string_capacity\": {}, \"nested_type_name\": \"{}\"}}}}",
            f.name, f.type_id, f.capacity, f.string_capacity, f.nested
        );
    }
    json.push_str("]}");
}

/// The JSON text whose SHA-256 is the hash (see the module's comment).
fn hashable_json(type_name: &str, definition: &str) -> Result<String, TypeHashError> {
    let texts = sections(type_name, definition)?;
    let main = full_name(type_name)?;
    // The main type and every type it refers to, transitively; each once, sorted by name.
    let mut described: BTreeMap<String, Vec<Field>> = BTreeMap::new();
    let mut todo = vec![main.clone()];
    while let Some(t) = todo.pop() {
        if described.contains_key(&t) {
            continue;
        }
        let text = texts.get(&t).ok_or_else(|| TypeHashError::Missing(t.clone()))?;
        let fields = parse_fields(&t, text)?;
        todo.extend(fields.iter().filter(|f| !f.nested.is_empty()).map(|f| f.nested.clone()));
        described.insert(t, fields);
    }
    let mut json = String::from("{\"type_description\": ");
    write_struct(&mut json, &main, &described[&main]);
    json.push_str(", \"referenced_type_descriptions\": [");
    for (i, (name, fields)) in described.iter().filter(|(n, _)| **n != main).enumerate() {
        if i > 0 {
            json.push_str(", ");
        }
        write_struct(&mut json, name, fields);
    }
    json.push_str("]}");
    Ok(json)
}

/// The RIHS01 hash of `type_name` (`pkg/msg/Type`) defined by `definition` (a `ros2msg` text
/// holding every nested type but the main one after a `MSG:` line), e.g.
/// `RIHS01_df668c74...` for `std_msgs/msg/String`:
///
/// ```
/// use bass_bridge::ros2::typehash::rihs01;
/// let h = rihs01("std_msgs/msg/String", "string data\n").unwrap();
/// assert_eq!(h, "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18");
/// ```
pub fn rihs01(type_name: &str, definition: &str) -> Result<String, TypeHashError> {
    let digest = Sha256::digest(hashable_json(type_name, definition)?.as_bytes());
    let mut s = String::from("RIHS01_");
    for b in digest {
        let _ = write!(s, "{b:02x}");
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use basskit::ros2;

    #[test]
    fn std_msgs_string_has_the_hash_rmw_zenoh_documents() {
        // rmw_zenoh's docs/design.md: 0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...
        assert_eq!(
            rihs01("std_msgs/msg/String", "string data\n").unwrap(),
            "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
        );
    }

    #[test]
    fn bass_types_have_the_hashes_rosbags_computes() {
        // Computed by rosbags 0.11.9 (`Typestore.hash_rihs01`) from the upstream
        // audio_common_msgs and builtin_interfaces definitions; the network suite recomputes
        // them live (tests/bridge/ros2_subscriber.py).
        let cases = [
            (
                ros2::AUDIO_DATA_STAMPED,
                ros2::AUDIO_DATA_STAMPED_DEFINITION,
                "RIHS01_6fc679d5a868ed68e4d301f1ef42abecc86140afb57d255656ff2d9e476ea9e3",
            ),
            (
                ros2::AUDIO_INFO,
                ros2::AUDIO_INFO_DEFINITION,
                "RIHS01_b3494d204e513d2cceefae1888e5be3da7c8c8ca31eb277f7b5b62f364bcb1fb",
            ),
            (
                // Port format 2.4: bound_ns, missing_channels, unaligned_channels at the end
                // (before them: RIHS01_ba33ad288bac5881c8d97098c1ceea79cb363163e465758aa7d18f480a816ae2).
                ros2::CHUNK_INFO,
                ros2::CHUNK_INFO_DEFINITION,
                "RIHS01_da155aa457e442f3007bab40ae66cbc6cf6401dd435e5c2202e5856e5a2a7aec",
            ),
            (
                "builtin_interfaces/msg/Time",
                "int32 sec\nuint32 nanosec\n",
                "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
            ),
        ];
        for (name, def, want) in cases {
            assert_eq!(rihs01(name, def).unwrap(), want, "{name}");
        }
    }

    #[test]
    fn comments_constants_and_defaults_do_not_change_the_hash() {
        let plain = rihs01("p/msg/T", "uint32 a\nstring b\n").unwrap();
        let noisy =
            "# a comment\nuint32 K=3  # constant\nstring S = \"x#y\"\n\nuint32 a 7 # default\nstring b\n";
        assert_eq!(rihs01("p/T", noisy).unwrap(), plain);
        assert_ne!(rihs01("p/msg/T", "uint32 a\nstring c\n").unwrap(), plain, "a field's name counts");
        assert_ne!(rihs01("p/msg/T", "uint64 a\nstring b\n").unwrap(), plain, "a field's type counts");
    }

    #[test]
    fn field_types_get_rosidl_ids() {
        let f = parse_fields(
            "p/msg/T",
            "uint8[] a\nint32[4] b\nfloat64[<=3] c\nstring<=8 d\nstring<=5[2] e\nHeader h\nU u\nq/V[] v\n",
        )
        .unwrap();
        let ids: Vec<_> =
            f.iter().map(|f| (f.type_id, f.capacity, f.string_capacity, f.nested.as_str())).collect();
        assert_eq!(
            ids,
            [
                (147, 0, 0, ""),
                (54, 4, 0, ""),
                (107, 3, 0, ""),
                (21, 0, 8, ""),
                (69, 2, 5, ""),
                (1, 0, 0, "std_msgs/msg/Header"),
                (1, 0, 0, "p/msg/U"),
                (145, 0, 0, "q/msg/V"),
            ]
        );
    }

    #[test]
    fn a_missing_dependency_or_a_bad_line_is_refused_by_name() {
        assert_eq!(rihs01("p/msg/T", "q/U u\n"), Err(TypeHashError::Missing("q/msg/U".into())));
        assert!(matches!(rihs01("p/msg/T", "uint32\n"), Err(TypeHashError::Line { .. })));
        assert!(matches!(rihs01("p/msg/T", "uint32 9lives\n"), Err(TypeHashError::Line { .. })));
        assert!(matches!(rihs01("p/msg/T", "float33 x\nq/U u\n"), Err(TypeHashError::Line { .. })));
        assert!(matches!(rihs01("not a name", "uint8 x\n"), Err(TypeHashError::Name(_))));
    }
}
