//! What can go wrong on the wire.

use thiserror::Error;

/// A received message that cannot be used.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum WireError {
    #[error(
        "a {len}-byte message is not a pushgrasp message (it lacks the 4-byte \"PG\" + version header)"
    )]
    NotAMessage { len: usize },
    #[error(
        "a message of protocol version {found} arrived; this build speaks version {expected}: every process of a run must come from the same pushgrasp build"
    )]
    Version { found: u16, expected: u16 },
    #[error("a protocol-version-{version} message does not decode: {why}")]
    Malformed { version: u16, why: String },
}

/// A transport that cannot carry a message.
#[derive(Debug, Error)]
pub enum TransportError {
    #[error("topic {topic}: the other side is gone")]
    Disconnected { topic: &'static str },
    #[error("topic {topic}: a {len}-byte message exceeds this topic's {max}-byte limit")]
    TooLarge {
        topic: &'static str,
        len: usize,
        max: usize,
    },
    #[error("topic {topic}: {why}")]
    Backend { topic: &'static str, why: String },
    /// The transport itself cannot be set up (a bad run id, no shared memory).
    #[error("transport: {why}")]
    Setup { why: String },
    #[error(transparent)]
    Wire(#[from] WireError),
}
