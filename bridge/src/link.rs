//! What crosses between hosts: the Zenoh key expressions of a run and how each is published.
//! Joined hosts publish up (steps, progress reports) under their own host name; the central
//! host publishes down (weights, orders) once for every host.

use anyhow::Result;
use zenoh::Session;
use zenoh::handlers::{FifoChannel, FifoChannelHandler, RingChannel, RingChannelHandler};
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::sample::Sample;

/// Every key of a run starts with this.
const PREFIX: &str = "pushgrasp";

/// Messages a lossless subscriber holds. Zenoh's reader of a link waits when the queue is
/// full, and then reads nothing from that host, not even the messages that keep its session
/// alive: the central host's steps queue is kept from filling by flow control (each host has
/// [`PARCELS_IN_FLIGHT`] at most), so this is room for that many from many hosts.
pub const SUBSCRIBER_QUEUE: usize = 1024;

/// Parcels a host may send before the central host acknowledges them.
pub const PARCELS_IN_FLIGHT: u64 = 8;

/// A stream between hosts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stream {
    /// Steps and episode ends, a joined host -> the central one: never dropped (a full
    /// queue blocks the publisher, and so the host's actors).
    Steps,
    /// Progress reports, a joined host -> the central one: cumulative, the newest wins.
    Status,
    /// The newest parcel the central host took from a host (flow control), central -> that
    /// host: cumulative, never dropped.
    Taken,
    /// Weights, the central host -> every joined host: the newest wins.
    Weights,
    /// Orders, the central host -> every joined host: never dropped.
    Control,
}

impl Stream {
    fn name(self) -> &'static str {
        match self {
            Stream::Steps => "steps",
            Stream::Status => "status",
            Stream::Taken => "taken",
            Stream::Weights => "weights",
            Stream::Control => "control",
        }
    }

    fn congestion(self) -> CongestionControl {
        match self {
            Stream::Steps | Stream::Control | Stream::Taken => CongestionControl::Block,
            Stream::Status | Stream::Weights => CongestionControl::Drop,
        }
    }

    /// Orders overtake data queued on the link.
    fn priority(self) -> Priority {
        match self {
            Stream::Control | Stream::Taken => Priority::InteractiveHigh,
            Stream::Status => Priority::DataHigh,
            Stream::Steps | Stream::Weights => Priority::Data,
        }
    }

    /// Whether a key names a host (its streams up, and what is for it alone) or is one for
    /// all hosts (the central host's weights and orders).
    fn per_host(self) -> bool {
        matches!(self, Stream::Steps | Stream::Status | Stream::Taken)
    }
}

/// A run's keys.
#[derive(Clone, Debug)]
pub struct Keys {
    run: String,
}

impl Keys {
    pub fn new(run_id: &str) -> Self {
        Self {
            run: format!("{PREFIX}/{run_id}"),
        }
    }

    /// The key of `stream` for `host` (ignored for the streams to every host).
    pub fn stream(&self, stream: Stream, host: &str) -> String {
        if stream.per_host() {
            format!("{}/{}/{host}", self.run, stream.name())
        } else {
            format!("{}/{}", self.run, stream.name())
        }
    }

    /// Every host's key of a stream up.
    pub fn every_host(&self, stream: Stream) -> String {
        format!("{}/{}/*", self.run, stream.name())
    }

    /// The host a key of a stream up names.
    pub fn host_of<'k>(&self, stream: Stream, key: &'k str) -> Option<&'k str> {
        key.strip_prefix(&self.run)?
            .strip_prefix('/')?
            .strip_prefix(stream.name())?
            .strip_prefix('/')
    }

    /// Where the central host answers joins.
    pub fn join(&self) -> String {
        format!("{}/join", self.run)
    }

    /// A joined host's liveliness token: present while its session is.
    pub fn host(&self, host: &str) -> String {
        format!("{}/hosts/{host}", self.run)
    }

    pub fn every_host_token(&self) -> String {
        format!("{}/hosts/*", self.run)
    }

    /// The central host's liveliness token.
    pub fn central(&self) -> String {
        format!("{}/central", self.run)
    }
}

/// A publisher for `stream` on `key`, as the stream is delivered.
pub fn publisher<'s>(session: &'s Session, stream: Stream, key: String) -> Result<Publisher<'s>> {
    use zenoh::Wait;
    session
        .declare_publisher(key.clone())
        .congestion_control(stream.congestion())
        .priority(stream.priority())
        .wait()
        .map_err(|e| anyhow::anyhow!("declaring the Zenoh publisher {key}: {e}"))
}

/// Publishes `bytes` on `key` once, as `stream` is delivered (for keys that change, such as
/// each host's acknowledgements, or are published seldom).
pub fn put(session: &Session, stream: Stream, key: String, bytes: Vec<u8>) -> Result<()> {
    use zenoh::Wait;
    session
        .put(key.clone(), bytes)
        .congestion_control(stream.congestion())
        .priority(stream.priority())
        .wait()
        .map_err(|e| anyhow::anyhow!("publishing on {key}: {e}"))
}

/// A subscriber to `key` that keeps only the newest messages: it never holds up the link.
pub fn newest_subscriber(
    session: &Session,
    key: String,
) -> Result<Subscriber<RingChannelHandler<Sample>>> {
    use zenoh::Wait;
    session
        .declare_subscriber(key.clone())
        .with(RingChannel::new(NEWEST_QUEUE))
        .wait()
        .map_err(|e| anyhow::anyhow!("declaring the Zenoh subscriber {key}: {e}"))
}

/// Messages a newest-wins subscriber keeps (reports of many actors between two reads).
const NEWEST_QUEUE: usize = 256;

/// A subscriber to `key` whose messages wait in a bounded queue (see [`SUBSCRIBER_QUEUE`]).
pub fn subscriber(
    session: &Session,
    key: String,
) -> Result<Subscriber<FifoChannelHandler<Sample>>> {
    use zenoh::Wait;
    session
        .declare_subscriber(key.clone())
        .with(FifoChannel::new(SUBSCRIBER_QUEUE))
        .wait()
        .map_err(|e| anyhow::anyhow!("declaring the Zenoh subscriber {key}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_name_the_run_and_the_host() {
        let keys = Keys::new("r1");
        let steps = keys.stream(Stream::Steps, "node-2");
        assert_eq!(steps, "pushgrasp/r1/steps/node-2");
        assert_eq!(keys.host_of(Stream::Steps, &steps), Some("node-2"));
        assert_eq!(keys.host_of(Stream::Status, &steps), None);
        assert_eq!(
            keys.stream(Stream::Weights, "node-2"),
            "pushgrasp/r1/weights"
        );
        assert_eq!(keys.every_host(Stream::Steps), "pushgrasp/r1/steps/*");
    }
}
