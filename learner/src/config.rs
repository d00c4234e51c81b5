//! The learning rule's hyper-parameters; the defaults are the paper's.

use std::ops::Bound;

use serde::{Deserialize, Serialize};
use sim::{ConfigError, above};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearningConfig {
    /// Adam's step size.
    pub learning_rate: f64,
    /// A step size falling geometrically from `learning_rate` (none: constant, as the
    /// paper).
    pub lr_decay: Option<LrDecay>,
    /// L2 weight decay (the paper prints 2^-5; the authors' code uses 2e-5).
    pub weight_decay: f32,
    pub beta_1: f32,
    pub beta_2: f32,
    /// Discount of the bootstrap term.
    pub gamma: f32,
    /// Where the Huber loss turns from quadratic to linear.
    pub huber_delta: f32,
    /// Polyak averaging: each update moves an average of the trained nets this fraction of
    /// the way to them (all the way while fewer than 1 / rate updates have been taken, so
    /// the average starts as a plain mean instead of leaning on the first nets).
    /// Checkpoints hold the average; 1 keeps no average, as the paper.
    pub polyak_rate: f32,
    /// Whether actors also act and bootstrap with the average (else with the trained nets,
    /// and only checkpoints hold the average).
    pub publish_average: bool,
    /// Each grasp also teaches its mirror image: the same label at the mirrored pixel of
    /// the mirrored observation, at the mirrored jaw angle. A grasp's outcome is the same in
    /// the mirror scene, for the jaws and every object shape are mirror-symmetric. Off by
    /// default, as the paper; it doubles a grasp update's items.
    pub mirror_grasps: bool,
    /// Each sample also teaches a copy of itself moved by up to this many pixels in each
    /// direction (a shift drawn afresh each update, never none, the pixel kept on the map):
    /// the same label at the moved pixel of the moved observation, at each rotation the
    /// sample teaches. Below the trunk's stride (4 pixels) a shift shows the same action at
    /// another phase of the nets' coarse grid. 0 (the paper) teaches no copy; any other
    /// value doubles an update's items.
    pub translate_samples: usize,
    /// Good Robot's SPOT-Q for grasps: where a grasp sample's Q map at its executed rotation
    /// peaks outside the sample's goal mask (a grasp there cannot take the goal), the update
    /// also teaches that pixel a failed grasp's label, 0. Samples whose goal is hidden are
    /// left as they are. Off (the paper) by default; it costs a forward pass of the batch.
    pub spot_q: bool,
    /// With an outcome head on the grasp net (`net.grasp_outcome_head`), each grasp's
    /// cross-entropy between that head's logit at the executed pixel and whether the grasp
    /// took the goal, times this, is added to the update's loss (weighted per sample as
    /// the Q loss). Unused without the head, which is how to leave it out.
    pub outcome_loss_weight: f32,
    /// The learner values a push's next state itself when the push is sampled (Double DQN:
    /// the best action there chosen by the trained nets and valued by target nets, a copy
    /// of the trained nets taken every this many updates), instead of using the value its
    /// actor computed when it acted; a relabelled push is valued for its own goal. Grasps
    /// keep their actor's value: a grasp ends its episode, and the state after it is the
    /// next episode's, with another goal. 0 (the paper): every value is the actor's.
    pub target_update_every: u64,
}

impl Default for LearningConfig {
    fn default() -> Self {
        Self {
            learning_rate: 1e-4,
            lr_decay: None,
            weight_decay: 2e-5,
            beta_1: 0.9,
            beta_2: 0.99,
            gamma: 0.5,
            huber_delta: 1.0,
            polyak_rate: 1.0,
            publish_average: true,
            mirror_grasps: false,
            translate_samples: 0,
            spot_q: false,
            outcome_loss_weight: 1.0,
            target_update_every: 0,
        }
    }
}

/// A step size that falls from the config's `learning_rate` to `to` over `over_updates`
/// learner updates, by the same factor each update, and stays at `to` after them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LrDecay {
    pub to: f64,
    pub over_updates: u64,
}

impl LearningConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        ConfigError::check_range("learning_rate", self.learning_rate, above(0.0))?;
        if let Some(decay) = &self.lr_decay {
            ConfigError::check_range("lr_decay.to", decay.to, above(0.0))?;
            if decay.over_updates == 0 {
                return Err(ConfigError::new(
                    "lr_decay.over_updates",
                    "must be at least 1",
                ));
            }
        }
        ConfigError::check_range("weight_decay", self.weight_decay, 0.0..)?;
        ConfigError::check_range("beta_1", self.beta_1, 0.0..1.0)?;
        ConfigError::check_range("beta_2", self.beta_2, 0.0..1.0)?;
        // Values are bounded by the rewards over 1 - gamma.
        ConfigError::check_range("gamma", self.gamma, 0.0..1.0)?;
        ConfigError::check_range("huber_delta", self.huber_delta, above(0.0))?;
        ConfigError::check_range("outcome_loss_weight", self.outcome_loss_weight, above(0.0))?;
        ConfigError::check_range(
            "polyak_rate",
            self.polyak_rate,
            (Bound::Excluded(0.0), Bound::Included(1.0)),
        )
    }
}
