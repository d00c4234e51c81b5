//! The learning rule of pushgrasp: bootstrap labels consistent with Q*, the Huber loss at the
//! executed pixel only (weighted by the replay's importance-sampling weights), Adam, which
//! net trains in which stage (the other frozen whole), the published nets (optionally a
//! Polyak average), optionally the learner's own bootstrap values from target nets (Double
//! DQN), checkpoints, and the trunks' generic visual pretraining.

pub mod adam;
pub mod averaging;
pub mod checkpoint;
pub mod config;
pub mod error;
mod items;
pub mod loss;
pub mod pretrain;
pub mod targets;
pub mod trainer;

pub use checkpoint::{Checkpoint, Manifest, SavedNets};
pub use config::{LearningConfig, LrDecay};
pub use error::LearnerError;
pub use loss::{executed_pixel_loss, outcome_loss};
pub use pretrain::{PretrainConfig, PretrainReport, pretrain};
pub use targets::NextState;
pub use trainer::{Sample, StepReport, TrainedNet, Trainer};
