//! The control plane: the broker's versioned request/reply protocol and its client.
//!
//! One Unix-domain `SOCK_SEQPACKET` socket per broker (`paths::socket_path(name)`); each
//! datagram is one whole message, a JSON object with `"version": "bass-control/2"`. A
//! request names its kind in `"request"`, a reply in `"reply"`; a message of another
//! version is refused by name. See docs/control-protocol.md for every message.
//!
//! ```text
//!  client                                         bassd
//!    | {"version":"bass-control/2",                 |
//!    |  "request":"acquire","device":"sim:sine"} -> |  validate, stop old, open device, new port
//!    | <- {"version":"bass-control/2",              |
//!    |     "reply":"acquired","epoch":7,"port":...} |
//! ```
//!
//! This module is the one definition of the protocol; the broker (`broker/`) encodes and
//! decodes with these same types:
//! - [`messages`] — the requests and replies (serde derives),
//! - [`wire`] — the datagram form and the version check,
//! - [`socket`] — the SEQPACKET socket calls (and the descriptor hand-over of `open-port`),
//! - [`client`] — [`Client`].

pub mod client;
pub mod messages;
pub mod socket;
pub mod wire;

pub use client::OpenedPort;
pub use client::{Client, DEFAULT_TIMEOUT};
pub use messages::{
    AcquireRequest, Acquired, DeviceInfo, DeviceStatus, ErrorKind, FollowerRequest, PortFd, ReplicaStatus,
    Reply, Request, Status, DEFAULT_CHANNELS, DEFAULT_CHUNKS_ON_PORT, DEFAULT_DEVICE,
    DEFAULT_FRAMES_PER_CHUNK, DEFAULT_SAMPLE_RATE,
};
pub use socket::{
    peer_credentials, recv_datagram, recv_reply, recv_reply_with_fd, send_datagram, send_reply,
    send_reply_with_fd, send_request, seqpacket_socket, PeerCred,
};
pub use wire::{WireError, MAX_MESSAGE, PROTOCOL};
