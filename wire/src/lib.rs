//! pushgrasp's wire: the transports that carry the messages its roles exchange (the
//! `messages` crate, re-exported here for the roles).
//!
//! Actors, the buffer, the learner and the launcher talk only through [`Topic`]s. A
//! [`Transport`] hands out raw publishers and subscribers for a topic; [`Outbox`] and
//! [`Inbox`] put the versioned [`Message`] encoding on top, so every role is written once and
//! runs over either implementation: [`ChannelTransport`] (crossbeam channels between threads)
//! or [`ShmTransport`] (iceoryx2 shared memory between processes). Every encoded message
//! starts with the protocol version; a message of another version is refused, never guessed at.

pub mod channel;
pub mod error;
pub mod shm;
pub mod topic;
pub mod transport;

pub use channel::ChannelTransport;
pub use error::TransportError;
// The messages, for the roles that send them over these transports.
pub use messages::{
    BatchMessage, Control, EpisodeEnd, Message, Origin, PROTOCOL_VERSION, PriorityUpdate, Role,
    SampleRequest, Status, Step, Weights, WireError, decode, encode_into, largest_step,
};
pub use shm::{
    LargestMessages, MAX_RUN_ID, SHM_PREFIX_VAR, ShmFootprint, ShmLimits, ShmTransport,
    StaleCleanup,
};
pub use topic::{Delivery, Fan, Topic};
pub use transport::{Inbox, Outbox, Publisher, Subscriber, Transport, WAITING_EVERY, Waiting};
