//! The networks' shape, every knob visible.

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QNetConfig {
    /// Output channels of each trunk's 3x3 stride-2 convolutions, in order: Q maps come out
    /// at 1 / 2^len of the padded input and are upsampled back. The default is the widest
    /// that keeps inference on all 16 rotations of both nets under 100 ms at 112 x 112 on two
    /// cores (`pushgrasp bench learner`).
    pub trunk_widths: Vec<usize>,
    /// Channels of the head's hidden 1x1 convolution (the paper's 64).
    pub head_width: usize,
}

impl Default for QNetConfig {
    fn default() -> Self {
        Self {
            trunk_widths: vec![8, 16],
            head_width: 64,
        }
    }
}

impl QNetConfig {
    /// How much the trunks shrink the padded input.
    pub fn downsample(&self) -> usize {
        1 << self.trunk_widths.len()
    }

    /// Multiply-adds x 2 of the convolutions of one net on one rotation of a padded input
    /// (batch norms, activations and the rotations are a few percent on top).
    pub fn flops_per_rotation(&self, padded: usize) -> f64 {
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
        let features: usize = channels.iter().sum();
        let area = (size * size) as f64;
        flops + 2.0 * area * (features * self.head_width + self.head_width) as f64
    }
}
