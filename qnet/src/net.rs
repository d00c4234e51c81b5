//! One primitive's Q-network: parallel trunks for colour, depth and goal mask, concatenated,
//! (optionally context convolutions over them together), then the paper's head (BN, ReLU,
//! 1x1 conv to 64, BN, ReLU, 1x1 conv to 1).

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, PaddingConfig2d};
use burn::prelude::*;

mod ops;

use crate::config::QNetConfig;

use ops::{convolve, expanded_conv, expanded_norm, norm_relu};

/// A 3x3 convolution (stride 2 to go down, or stride 1 with a dilation to see further),
/// batch norm and ReLU; padded so only the stride changes the size. The convolution has no
/// bias, as every one followed by a batch norm here (as in the paper's DenseNet trunks and
/// its head): the norm subtracts it again, so its gradient is only rounding noise, which
/// Adam's normalised steps would turn into steps of the full learning rate. In a
/// rotation-equivariant net the convolution holds base kernels and the norm one channel a
/// field ([`crate::equivariant`]).
#[derive(Module, Debug)]
pub struct ConvBlock {
    pub(crate) conv: Conv2d,
    pub(crate) norm: BatchNorm,
    /// Channels a field in and out: `[1, 1]` in an ordinary net.
    #[module(skip)]
    pub(crate) groups: [usize; 2],
}

impl ConvBlock {
    fn down(channels_in: usize, channels_out: usize, groups: [usize; 2], device: &Device) -> Self {
        Self::new([channels_in, channels_out], 2, 1, groups, device)
    }

    fn context(channels: usize, dilation: usize, group: usize, device: &Device) -> Self {
        Self::new([channels, channels], 1, dilation, [group, group], device)
    }

    fn new(
        channels: [usize; 2],
        stride: usize,
        dilation: usize,
        groups: [usize; 2],
        device: &Device,
    ) -> Self {
        let fields = channels[1] / groups[1];
        Self {
            conv: Conv2dConfig::new([channels[0], fields], [3, 3])
                .with_bias(false)
                .with_stride([stride, stride])
                .with_dilation([dilation, dilation])
                .with_padding(PaddingConfig2d::Explicit(
                    dilation, dilation, dilation, dilation,
                ))
                .init(device),
            norm: BatchNormConfig::new(fields).init(device),
            groups,
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let y = convolve(&self.conv, self.groups, x);
        norm_relu(&self.norm, self.groups[1], y)
    }

    /// This block as an ordinary one computing the same function in inference.
    fn expanded(&self) -> Self {
        Self {
            conv: expanded_conv(&self.conv, self.groups),
            norm: expanded_norm(&self.norm, self.groups[1]),
            groups: [1, 1],
        }
    }
}

/// Blocks applied in turn.
#[derive(Module, Debug)]
pub struct Trunk {
    pub(crate) blocks: Vec<ConvBlock>,
}

impl Trunk {
    /// Down blocks over one kind of input plane, then its context blocks unless the config
    /// fuses them.
    fn new(channels_in: usize, config: &QNetConfig, device: &Device) -> Self {
        let mut blocks = Vec::new();
        let (mut channels, mut group_in) = (channels_in, 1);
        for &width in &config.trunk_widths {
            let groups = [group_in, config.group()];
            blocks.push(ConvBlock::down(channels, width, groups, device));
            (channels, group_in) = (width, config.group());
        }
        if !config.fuse_context {
            blocks.extend(Self::context(channels, config, device).blocks);
        }
        Self { blocks }
    }

    /// The config's context blocks alone, over `channels` features.
    fn context(channels: usize, config: &QNetConfig, device: &Device) -> Self {
        let blocks = config
            .context_dilations
            .iter()
            .map(|&dilation| ConvBlock::context(channels, dilation, config.group(), device))
            .collect();
        Self { blocks }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.blocks.iter().fold(x, |x, block| block.forward(x))
    }

    fn expanded(&self) -> Self {
        Self {
            blocks: self.blocks.iter().map(ConvBlock::expanded).collect(),
        }
    }
}

/// The Q-network of one primitive.
#[derive(Module, Debug)]
pub struct PrimitiveNet {
    pub(crate) colour: Trunk,
    pub(crate) depth: Trunk,
    pub(crate) mask: Trunk,
    /// Context blocks over the trunks' features together (none unless `fuse_context`).
    pub(crate) fused: Trunk,
    pub(crate) head_norm_in: BatchNorm,
    pub(crate) head_hidden: Conv2d,
    pub(crate) head_norm_hidden: BatchNorm,
    pub(crate) head_out: Conv2d,
    /// The outcome logit's 1x1 convolution beside `head_out`, when the net has one
    /// (`QNetConfig::grasp_outcome_head`).
    pub(crate) outcome_out: Option<Conv2d>,
    /// Channels a field ([`QNetConfig::group`]): 1 in an ordinary net.
    #[module(skip)]
    pub(crate) group: usize,
}

impl PrimitiveNet {
    /// A fresh net; `outcome`: with an outcome logit beside its Q value.
    pub fn new(config: &QNetConfig, outcome: bool, device: &Device) -> Self {
        // Trunks first, then the head: the order the weights are drawn in.
        let colour = Trunk::new(3, config, device);
        let depth = Trunk::new(1, config, device);
        let mask = Trunk::new(1, config, device);
        let fused = if config.fuse_context {
            Trunk::context(Self::features(config), config, device)
        } else {
            Trunk { blocks: Vec::new() }
        };
        let (head_norm_in, head_hidden, head_norm_hidden, head_out) = Self::head(config, device);
        Self {
            colour,
            depth,
            mask,
            fused,
            head_norm_in,
            head_hidden,
            head_norm_hidden,
            head_out,
            outcome_out: outcome.then(|| Self::head_output(config, device)),
            group: config.group(),
        }
    }

    /// This net as an ordinary one (one channel a field, every weight laid out) computing
    /// the same function in inference: what other engines are built from. An ordinary net
    /// is itself.
    pub fn expanded(&self) -> Self {
        if self.group == 1 {
            return self.clone();
        }
        let groups = [self.group; 2];
        Self {
            colour: self.colour.expanded(),
            depth: self.depth.expanded(),
            mask: self.mask.expanded(),
            fused: self.fused.expanded(),
            head_norm_in: expanded_norm(&self.head_norm_in, self.group),
            head_hidden: expanded_conv(&self.head_hidden, groups),
            head_norm_hidden: expanded_norm(&self.head_norm_hidden, self.group),
            head_out: expanded_conv(&self.head_out, groups),
            outcome_out: self
                .outcome_out
                .as_ref()
                .map(|conv| expanded_conv(conv, groups)),
            group: 1,
        }
    }

    /// Channels a field of its layers: 1 in an ordinary net, and in an equivariant net
    /// laid out in full ([`Self::expanded`]).
    pub fn group(&self) -> usize {
        self.group
    }

    /// The action angles a quarter turn apart that one pass scores: the Q maps of its
    /// output, one a field's channel (the same in the net laid out in full).
    pub fn angles_per_pass(&self) -> usize {
        self.head_out.weight.dims()[0] * self.group
    }

    /// Starts the head afresh, as a new net's, keeping the trunks (pretrained on another
    /// task).
    pub fn fresh_head(&mut self, config: &QNetConfig, device: &Device) {
        (
            self.head_norm_in,
            self.head_hidden,
            self.head_norm_hidden,
            self.head_out,
        ) = Self::head(config, device);
        if self.outcome_out.is_some() {
            self.outcome_out = Some(Self::head_output(config, device));
        }
    }

    /// The paper's head over the trunks' features: BN, 1x1 conv to `head_width` (no bias:
    /// a BN follows, as after a [`ConvBlock`]'s), BN, 1x1 conv to one Q value (a field:
    /// one per quarter turn in an equivariant net).
    fn head(config: &QNetConfig, device: &Device) -> (BatchNorm, Conv2d, BatchNorm, Conv2d) {
        let (features, group) = (Self::features(config), config.group());
        (
            BatchNormConfig::new(features / group).init(device),
            Conv2dConfig::new([features, config.head_width / group], [1, 1])
                .with_bias(false)
                .init(device),
            BatchNormConfig::new(config.head_width / group).init(device),
            Self::head_output(config, device),
        )
    }

    /// A 1x1 convolution from the head's hidden features to one value a pixel (a field).
    fn head_output(config: &QNetConfig, device: &Device) -> Conv2d {
        Conv2dConfig::new([config.head_width, 1], [1, 1]).init(device)
    }

    /// The three trunks' last widths side by side (a trunk without blocks passes its
    /// planes).
    fn features(config: &QNetConfig) -> usize {
        let last = |planes: usize| config.trunk_widths.last().copied().unwrap_or(planes);
        last(3) + 2 * last(1)
    }

    /// Low-resolution Q maps `[n, group, P / d, P / d]` of rotated inputs colour
    /// `[n, 3, P, P]`, depth and mask `[n, 1, P, P]`: map `g` for the action turned `g`
    /// quarter turns from the input's rotation ([`crate::equivariant`]).
    pub fn forward(&self, colour: Tensor<4>, depth: Tensor<4>, mask: Tensor<4>) -> Tensor<4> {
        self.output(&self.head_out, self.hidden(colour, depth, mask))
    }

    /// [`Self::forward`]'s Q maps and, when the net has an outcome head, its logit maps
    /// after them: `[n, group x (1 or 2), P / d, P / d]`.
    pub fn forward_with_outcome(
        &self,
        colour: Tensor<4>,
        depth: Tensor<4>,
        mask: Tensor<4>,
    ) -> Tensor<4> {
        let hidden = self.hidden(colour, depth, mask);
        match &self.outcome_out {
            Some(outcome) => Tensor::cat(
                vec![
                    self.output(&self.head_out, hidden.clone()),
                    self.output(outcome, hidden),
                ],
                1,
            ),
            None => self.output(&self.head_out, hidden),
        }
    }

    /// One of the head's 1x1 output convolutions over its hidden features.
    fn output(&self, conv: &Conv2d, hidden: Tensor<4>) -> Tensor<4> {
        convolve(conv, [self.group; 2], hidden)
    }

    /// Whether the net has an outcome head.
    pub fn has_outcome(&self) -> bool {
        self.outcome_out.is_some()
    }

    /// The head's hidden features, before its output convolutions.
    fn hidden(&self, colour: Tensor<4>, depth: Tensor<4>, mask: Tensor<4>) -> Tensor<4> {
        let features = Tensor::cat(
            vec![
                self.colour.forward(colour),
                self.depth.forward(depth),
                self.mask.forward(mask),
            ],
            1,
        );
        let group = self.group;
        let x = norm_relu(&self.head_norm_in, group, self.fused.forward(features));
        let hidden = convolve(&self.head_hidden, [group; 2], x);
        norm_relu(&self.head_norm_hidden, group, hidden)
    }
}

#[cfg(test)]
mod tests;
