//! What can go wrong on a transport.

use messages::WireError;
use thiserror::Error;

use crate::topic::Topic;

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

impl TransportError {
    /// An iceoryx2 call on `topic` that failed while `what`.
    pub(crate) fn iceoryx2(topic: Topic, what: &str, e: impl std::fmt::Display) -> Self {
        TransportError::Backend {
            topic: topic.name(),
            why: format!("iceoryx2: {what}: {e}"),
        }
    }
}
