//! The control protocol's wire form: one JSON object per SEQPACKET datagram, with the
//! protocol version in its `"version"` field and the message's own fields beside it.
//!
//! ```text
//! {"version":"bass-control/2","request":"acquire","device":"sim:sine","sample_rate":48000}
//!  \______ envelope _______/ \_______ the message (messages.rs, serde) ________________/
//! ```
//!
//! A datagram of any other version is refused by name: the `bass-control/1` key=value text
//! of earlier releases is recognised by its first line, so an old peer is told which
//! versions meet rather than that its bytes are garbage.

use serde::de::DeserializeOwned;
use serde::Serialize;

use super::messages::{Reply, Request};

/// The protocol version this library speaks (the `"version"` of every message).
pub const PROTOCOL: &str = "bass-control/2";
/// Largest message (bytes) either side sends or accepts.
pub const MAX_MESSAGE: usize = 64 * 1024;

/// Why a datagram is not a message of this protocol version.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// A message of another protocol version (`found`, e.g. `bass-control/1`).
    #[error("the message is {found}, this side speaks {PROTOCOL}")]
    Version {
        /// The version the message names (or `unknown`).
        found: String,
    },
    /// Not a message at all, or a message with a malformed or unknown field.
    #[error("{0}")]
    Malformed(String),
}

/// The version-1 text form started with this (`bass-control/1 <verb>\n...`).
const TEXT_PREFIX: &[u8] = b"bass-control/";

#[derive(Serialize)]
struct Envelope<'a, T> {
    version: &'a str,
    #[serde(flatten)]
    body: &'a T,
}

fn encode<T: Serialize>(body: &T) -> Vec<u8> {
    // Serialising these types cannot fail: plain structs and enums with string keys (a
    // non-UTF-8 port path would be the only failure, and ports are named by bass).
    serde_json::to_vec(&Envelope { version: PROTOCOL, body }).unwrap_or_else(|e| {
        let failed = serde_json::json!({ "version": PROTOCOL, "encoding-failed": e.to_string() });
        failed.to_string().into_bytes()
    })
}

fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, WireError> {
    if bytes.starts_with(TEXT_PREFIX) {
        // The text form of version 1 (or a later text form): name its version.
        let line = bytes.split(|b| *b == b'\n').next().unwrap_or_default();
        let token = line.split(|b| *b == b' ').next().unwrap_or_default();
        let found = String::from_utf8_lossy(&token[..token.len().min(40)]).into_owned();
        return Err(WireError::Version { found });
    }
    if bytes.len() > MAX_MESSAGE {
        return Err(WireError::Malformed(format!("message of {} bytes exceeds {MAX_MESSAGE}", bytes.len())));
    }
    let value: serde_json::Value = serde_json::from_slice(bytes)
        .map_err(|e| WireError::Malformed(format!("not a JSON message ({e})")))?;
    let Some(object) = value.as_object() else {
        return Err(WireError::Malformed("the message is not a JSON object".into()));
    };
    match object.get("version") {
        Some(serde_json::Value::String(v)) if v == PROTOCOL => {}
        Some(serde_json::Value::String(v)) => {
            let found = v.chars().take(40).collect();
            return Err(WireError::Version { found });
        }
        Some(other) => return Err(WireError::Version { found: format!("{:.40}", other.to_string()) }),
        None => return Err(WireError::Version { found: "a message without \"version\"".into() }),
    }
    serde_json::from_value(value).map_err(|e| WireError::Malformed(e.to_string()))
}

/// The wire form of a request.
pub fn encode_request(r: &Request) -> Vec<u8> {
    encode(r)
}

/// Decodes a request (the version is checked first).
pub fn decode_request(bytes: &[u8]) -> Result<Request, WireError> {
    decode(bytes)
}

/// The wire form of a reply.
pub fn encode_reply(r: &Reply) -> Vec<u8> {
    encode(r)
}

/// Decodes a reply (the version is checked first).
pub fn decode_reply(bytes: &[u8]) -> Result<Reply, WireError> {
    decode(bytes)
}

/// Whether `bytes` is in the version-1 text form; such a peer cannot read JSON, so the
/// broker answers it with [`v1_error`].
pub fn is_v1_text(bytes: &[u8]) -> bool {
    bytes.starts_with(b"bass-control/1 ")
}

/// A version-1 `error` reply (`code=version`), in the one form a version-1 client reads:
/// it shows `message` followed by `[version]`.
pub fn v1_error(message: &str) -> Vec<u8> {
    let one_line = message.replace('\\', "\\\\").replace('\n', "\\n");
    format!("bass-control/1 error\ncode=version\nmessage={one_line}\n").into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::messages::{AcquireRequest, DeviceInfo, ErrorKind, Status};

    #[test]
    fn requests_and_replies_round_trip() {
        let reqs = [
            Request::ListDevices,
            Request::Stop,
            Request::Status,
            Request::OpenPort,
            Request::Acquire(AcquireRequest { format: Some("S16_LE".into()), ..Default::default() }),
        ];
        for r in reqs {
            assert_eq!(decode_request(&encode_request(&r)).unwrap(), r);
        }
        let replies = [
            Reply::Devices {
                devices: vec![DeviceInfo {
                    name: "hw:CARD=X,DEV=0".into(),
                    description: "a\nb\t\"c\"".into(),
                }],
            },
            Reply::Stopped { message: "stopped".into() },
            Reply::PortFd(crate::control::messages::PortFd { epoch: 3, size: 1 << 20 }),
            Reply::PortFile { port: "/run/bass/bass-default.port".into() },
            Reply::Status(Status {
                rate_estimate_hz: 48000.25,
                device: "sim:sine".into(),
                ..Default::default()
            }),
            Reply::error(ErrorKind::InvalidArgument, "nFramesPerChunk = 0"),
        ];
        for r in replies {
            assert_eq!(decode_reply(&encode_reply(&r)).unwrap(), r);
        }
    }

    #[test]
    fn an_acquire_without_fields_takes_the_seed_defaults() {
        let r = decode_request(br#"{"version":"bass-control/2","request":"acquire"}"#).unwrap();
        assert_eq!(r, Request::Acquire(AcquireRequest::default()));
    }

    #[test]
    fn other_versions_are_named() {
        for (bytes, found) in [
            (&b"bass-control/1 status\n"[..], "bass-control/1"),
            (b"bass-control/1 ok\nepoch=3\n", "bass-control/1"),
            (br#"{"version":"bass-control/3","request":"status"}"#, "bass-control/3"),
            (br#"{"request":"status"}"#, "a message without \"version\""),
        ] {
            let e = decode_request(bytes).unwrap_err();
            assert_eq!(e, WireError::Version { found: found.into() }, "{bytes:?}");
            assert!(e.to_string().contains(PROTOCOL), "{e}");
        }
    }

    #[test]
    fn malformed_messages_are_named_errors() {
        for bad in [
            &b"hello"[..],
            b"\xff\xfe",
            b"[1,2]",
            br#"{"version":"bass-control/2","request":"explode"}"#,
            br#"{"version":"bass-control/2","request":"acquire","sample_rate":"fast"}"#,
            br#"{"version":"bass-control/2","request":"acquire","frames_per_chunk":-1}"#,
            br#"{"version":"bass-control/2","reply":"stopped"}"#,
        ] {
            assert!(matches!(decode_request(bad), Err(WireError::Malformed(_))), "{bad:?}");
        }
    }

    #[test]
    fn error_kind_names_are_the_serde_names() {
        use ErrorKind::*;
        for k in [InvalidArgument, Device, Permission, Version, Protocol, Internal] {
            assert_eq!(serde_json::to_value(k).unwrap(), k.as_str(), "{k:?}");
        }
    }

    #[test]
    fn v1_errors_are_v1_text() {
        let e = v1_error("this broker speaks bass-control/2");
        assert_eq!(e, b"bass-control/1 error\ncode=version\nmessage=this broker speaks bass-control/2\n");
        assert!(is_v1_text(b"bass-control/1 acquire\n"));
    }
}
