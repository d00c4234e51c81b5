//! The transport interface, and the typed ends every role uses on top of it.

use std::time::Duration;

use crate::error::TransportError;
use crate::topic::Topic;
use messages::{Message, decode, encode_into};

/// Hands out the two ends of a topic. Ends are made in the thread that uses them.
pub trait Transport {
    fn publisher(&self, topic: Topic) -> Result<Box<dyn Publisher>, TransportError>;
    fn subscriber(&self, topic: Topic) -> Result<Box<dyn Subscriber>, TransportError>;
}

/// How often a send waiting for room calls its `waiting` (see [`Publisher::send_waiting`]).
pub const WAITING_EVERY: Duration = Duration::from_millis(250);

/// What a waiting send calls now and then: a role that must be heard while it waits (an
/// actor held back by the buffer's rate limiter) reports from it.
pub type Waiting<'a> = &'a mut dyn FnMut() -> Result<(), TransportError>;

/// Sends raw messages on one topic, as its [`Delivery`](crate::Delivery) says.
pub trait Publisher {
    /// Sends `bytes`; on a lossless topic it waits while the subscriber's buffer is full,
    /// calling `waiting` about every [`WAITING_EVERY`] meanwhile. Shared memory, on a topic
    /// several read (one to many), waits for the slowest reader without calling it.
    fn send_waiting(&mut self, bytes: &[u8], waiting: Waiting<'_>) -> Result<(), TransportError>;

    /// [`Publisher::send_waiting`], with nothing to do while it waits.
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.send_waiting(bytes, &mut || Ok(()))
    }

    /// Connects subscribers that joined since the last send, handing them the topic's
    /// history. Shared memory needs it: a publisher of a topic with history (weights,
    /// orders) that may go a while without sending calls it now and then, or late
    /// subscribers wait for its next message. Channels deliver history on subscription.
    fn refresh(&mut self) -> Result<(), TransportError> {
        Ok(())
    }
}

/// Receives raw messages on one topic.
pub trait Subscriber {
    /// Hands the oldest unread message to `sink` (in place where the transport allows) and
    /// returns true, or returns false when none is waiting.
    fn receive(&mut self, sink: &mut dyn FnMut(&[u8])) -> Result<bool, TransportError>;

    /// Connects to publishers that joined since the last look, as `receive` does first:
    /// from then on what they send stays readable after they exit (shared memory; channels
    /// keep every message anyway). A reader that goes a while without receiving calls it.
    fn refresh(&mut self) -> Result<(), TransportError> {
        Ok(())
    }
}

/// Sends [`Message`]s on a topic.
pub struct Outbox {
    publisher: Box<dyn Publisher>,
    encoded: Vec<u8>,
}

impl Outbox {
    pub fn open(transport: &dyn Transport, topic: Topic) -> Result<Self, TransportError> {
        Ok(Self {
            publisher: transport.publisher(topic)?,
            encoded: Vec::new(),
        })
    }

    pub fn send(&mut self, message: &Message) -> Result<(), TransportError> {
        self.send_waiting(message, &mut || Ok(()))
    }

    /// See [`Publisher::send_waiting`].
    pub fn send_waiting(
        &mut self,
        message: &Message,
        waiting: Waiting<'_>,
    ) -> Result<(), TransportError> {
        encode_into(message, &mut self.encoded);
        self.publisher.send_waiting(&self.encoded, waiting)
    }

    /// See [`Publisher::refresh`].
    pub fn refresh(&mut self) -> Result<(), TransportError> {
        self.publisher.refresh()
    }

    /// Sends bytes as they are: what a process of another build would send.
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.publisher.send(bytes)
    }
}

/// Receives [`Message`]s on a topic, refusing any of another protocol version.
pub struct Inbox {
    subscriber: Box<dyn Subscriber>,
}

impl Inbox {
    pub fn open(transport: &dyn Transport, topic: Topic) -> Result<Self, TransportError> {
        Ok(Self {
            subscriber: transport.subscriber(topic)?,
        })
    }

    /// The next message, if one is waiting.
    pub fn try_recv(&mut self) -> Result<Option<Message>, TransportError> {
        let mut decoded = None;
        self.subscriber
            .receive(&mut |bytes| decoded = Some(decode(bytes)))?;
        Ok(decoded.transpose()?)
    }

    /// See [`Subscriber::refresh`].
    pub fn refresh(&mut self) -> Result<(), TransportError> {
        self.subscriber.refresh()
    }

    /// Every message waiting now, oldest first; stops at the first bad one.
    pub fn drain(&mut self) -> Result<Vec<Message>, TransportError> {
        let mut messages = Vec::new();
        while let Some(message) = self.try_recv()? {
            messages.push(message);
        }
        Ok(messages)
    }
}
