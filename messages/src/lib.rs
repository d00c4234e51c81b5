//! The messages of a pushgrasp run and their encoding: what the actors, the buffer, the
//! learner and the launcher say to each other, and what a run's logs keep of it. Every
//! encoded message starts with the protocol version; one of another version is refused,
//! never guessed at. The transports that carry them are the `wire` crate's: a reader of a
//! run needs the messages, not shared memory.

pub mod codec;
pub mod error;
pub mod message;

pub use codec::{PROTOCOL_VERSION, decode, encode_into, largest_step};
pub use error::WireError;
pub use message::{
    BatchMessage, Control, EpisodeEnd, Message, Origin, PriorityUpdate, Role, SampleRequest,
    Status, Step, Weights,
};
