//! The networks' shape, every knob visible.

use serde::{Deserialize, Serialize};
use sim::ConfigError;

#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QNetConfig {
    /// Output channels of each trunk's 3x3 stride-2 convolutions, in order: Q maps come out
    /// at 1 / 2^len of the padded input and are upsampled back. The default is the widest
    /// that keeps inference on all 16 rotations of both nets under 100 ms at 112 x 112 on two
    /// cores (`pushgrasp bench learner`).
    pub trunk_widths: Vec<usize>,
    /// Dilations of each trunk's 3x3 stride-1 convolutions after the strided ones, at the
    /// low resolution and the last width. They widen what a Q value sees (an object, the
    /// neighbours in the jaws' way) without coarsening the map: two stride-2 layers alone see
    /// 7 input pixels, and each of these adds 2 x dilation x 2^len(trunk_widths).
    /// (Left out of the serialised config when empty, so checkpoints of nets without it
    /// keep their config hash.)
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub context_dilations: Vec<usize>,
    /// Run the context convolutions once over the three trunks' features side by side
    /// instead of in each trunk: a Q value then sees where the goal's mask lies beside the
    /// heights around it (the neighbours in the jaws' way), where separate trunks meet only
    /// in the head's 1x1 convolutions, pixel by pixel. (Left out of the serialised config
    /// when off.)
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub fuse_context: bool,
    /// Channels of the head's hidden 1x1 convolution (the paper's 64).
    pub head_width: usize,
    /// Give the grasp net a second 1x1 output beside its Q value: the logit of the grasp
    /// succeeding, trained on the outcome alone with a cross-entropy loss
    /// (`learning.outcome_loss_weight`). The policy never reads it; it teaches the features
    /// a signal free of the Q label's bootstrapped value. (Left out of the serialised
    /// config when off.)
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub grasp_outcome_head: bool,
    /// Tie every convolution's weights across the four quarter turns (group convolutions,
    /// [`crate::equivariant`]): each width is then `width / 4` fields of 4 channels, one per
    /// quarter turn, and one pass over an input rotated by -theta scores the actions at
    /// theta, theta + 90, theta + 180 and theta + 270 degrees, so the 16 rotations take 4
    /// passes and what is learnt at one angle holds at the three others. (Left out of the
    /// serialised config when off.)
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub rotation_equivariant: bool,
}

impl Default for QNetConfig {
    fn default() -> Self {
        Self {
            trunk_widths: vec![8, 16],
            context_dilations: Vec::new(),
            fuse_context: false,
            head_width: 64,
            grasp_outcome_head: false,
            rotation_equivariant: false,
        }
    }
}

impl QNetConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.trunk_widths.is_empty() || self.trunk_widths.contains(&0) {
            let why = format!(
                "{:?}: needs at least one width, each at least 1",
                self.trunk_widths
            );
            return Err(ConfigError::new("trunk_widths", why));
        }
        if self.context_dilations.contains(&0) {
            let why = format!(
                "{:?}: each dilation must be at least 1",
                self.context_dilations
            );
            return Err(ConfigError::new("context_dilations", why));
        }
        if self.fuse_context && self.context_dilations.is_empty() {
            let why = "true needs context_dilations to fuse";
            return Err(ConfigError::new("fuse_context", why));
        }
        if self.head_width == 0 {
            return Err(ConfigError::new("head_width", "must be at least 1"));
        }
        let group = self.group();
        if group > 1 {
            let widths = self.trunk_widths.iter().chain([&self.head_width]);
            if widths.clone().any(|width| width % group != 0) {
                let why = format!(
                    "true needs every trunk width and the head width to be a multiple of \
                     {group} (fields of one channel a quarter turn), not {:?} and {}",
                    self.trunk_widths, self.head_width
                );
                return Err(ConfigError::new("rotation_equivariant", why));
            }
        }
        Ok(())
    }

    /// Channels a field of the nets' features: the rotations each pass scores at once.
    pub fn group(&self) -> usize {
        if self.rotation_equivariant {
            crate::equivariant::QUARTER_TURNS
        } else {
            1
        }
    }

    /// How much the trunks shrink the padded input.
    pub fn downsample(&self) -> usize {
        1 << self.trunk_widths.len()
    }

    /// Multiply-adds x 2 of the convolutions of one net's pass over one rotated padded input
    /// (batch norms, activations and the rotations are a few percent on top): one rotation's
    /// Q map, or `group` of them in an equivariant net.
    pub fn flops_per_pass(&self, padded: usize) -> f64 {
        let mut flops = 0.0;
        let mut size = padded;
        let mut channels = [3usize, 1, 1];
        for &width in &self.trunk_widths {
            size = size.div_ceil(2);
            let area = (size * size) as f64;
            for c in &mut channels {
                flops += 2.0 * area * (width * *c * 9) as f64;
                *c = width;
            }
        }
        let area = (size * size) as f64;
        let features: usize = channels.iter().sum();
        let context_channels = if self.fuse_context {
            vec![features]
        } else {
            channels.to_vec()
        };
        for _ in &self.context_dilations {
            for c in &context_channels {
                flops += 2.0 * area * (c * c * 9) as f64;
            }
        }
        flops + 2.0 * area * (features * self.head_width + self.head_width * self.group()) as f64
    }
}
