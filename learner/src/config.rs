//! The learning rule's hyper-parameters; the defaults are the paper's.

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearningConfig {
    /// Adam's step size.
    pub learning_rate: f64,
    /// L2 weight decay (the paper prints 2^-5; the authors' code uses 2e-5).
    pub weight_decay: f32,
    pub beta_1: f32,
    pub beta_2: f32,
    /// Discount of the bootstrap term.
    pub gamma: f32,
    /// Where the Huber loss turns from quadratic to linear.
    pub huber_delta: f32,
    /// Polyak averaging: each update moves the published nets (what actors act and
    /// bootstrap with, and what checkpoints hold) this fraction of the way to the trained
    /// ones. 1 publishes the trained nets themselves, as the paper.
    pub polyak_rate: f32,
}

impl Default for LearningConfig {
    fn default() -> Self {
        Self {
            learning_rate: 1e-4,
            weight_decay: 2e-5,
            beta_1: 0.9,
            beta_2: 0.99,
            gamma: 0.5,
            huber_delta: 1.0,
            polyak_rate: 1.0,
        }
    }
}
