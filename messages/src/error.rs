//! What can be wrong with the bytes of a received message.

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
