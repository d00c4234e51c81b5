//! pushgrasp's replay buffer: what the actors' steps become before the learner sees them.
//!
//! Steps arrive per episode and wait in an [`EpisodeAssembler`] until the episode ends; then
//! their observations are compressed (`experience::PackedObservation`, shared by a step's
//! relabelled copies) and they are stored, with the goal-relabelled copies the paper
//! implies, in a [`PrioritizedReplay`] that keeps push and grasp experience in separate
//! fixed-size rings, each with a [`SumTree`] for proportional prioritisation (alpha, annealed
//! beta, importance-sampling weights, Ape-X initial priorities). A Reverb-style [`RateLimiter`]
//! holds the learner's samples to a ratio of the inserts. [`ReplayBuffer`] ties them together
//! and snapshots to a file. A plain library: it knows nothing of how steps and batches travel.

mod chunks;
pub mod config;
pub mod error;
pub mod rate_limit;
pub mod relabel;
pub mod replay;
mod ring;
pub mod snapshot;
pub mod store;
pub mod sum_tree;

pub use config::{BufferConfig, Capacity, bytes_per_step};
pub use error::{AssembleError, ReplayError, SnapshotError, SnapshotErrorKind};
pub use rate_limit::RateLimiter;
pub use relabel::{EpisodeAssembler, Pending, Ready};
pub use replay::{Batch, PrioritizedReplay, unpack};
pub use store::{ReplayBuffer, ReplayCopy, Serving, Stats};
pub use sum_tree::SumTree;
