//! pushgrasp across machines. Each host keeps its own shared memory (iceoryx2) among its
//! processes; one bridge per host carries what must cross: joined hosts' steps, episode ends
//! and progress reports to the central host, where they enter the buffer's topic like any
//! local actor's, and the learner's weights (once per host) and the launcher's orders back.
//! The hosts meet over Zenoh, which checks every joiner against the run's secret.

pub mod admission;
pub mod central;
pub mod host;
pub mod join;
pub mod link;
pub mod parcel;
pub mod secret;
pub mod session;
pub mod traces;

pub use admission::{Admission, HostNews};
pub use central::Central;
pub use host::HostBridge;
pub use join::{JoinRequest, Placement};
pub use link::{Keys, Stream};
pub use secret::RunSecret;
pub use session::Endpoint;
pub use zenoh;
