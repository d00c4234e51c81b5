//! One primitive's Q-network: parallel trunks for colour, depth and goal mask, concatenated,
//! (optionally context convolutions over them together), then the paper's head (BN, ReLU,
//! 1x1 conv to 64, BN, ReLU, 1x1 conv to 1).

use burn::module::{Param, RunningState};
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, PaddingConfig2d};
use burn::prelude::*;
use burn::tensor::module;
use burn::tensor::ops::ConvOptions;

use crate::batch_norm;
use crate::config::QNetConfig;
use crate::equivariant;
use crate::gemm_conv::{self, Taps};

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

/// `norm` and a ReLU over `x` whose fields have `group` channels each, sharing a field's
/// statistics.
fn norm_relu(norm: &BatchNorm, group: usize, x: Tensor<4>) -> Tensor<4> {
    if group == 1 {
        return batch_norm::forward_relu(norm, x);
    }
    equivariant::unfields(
        batch_norm::forward_relu(norm, equivariant::fields(x, group)),
        group,
    )
}

/// `conv`'s weights with its base kernels laid out for `groups`, and its bias given to
/// every channel of a field ([`equivariant::expand`]).
fn full_weights(conv: &Conv2d, groups: [usize; 2]) -> (Tensor<4>, Option<Tensor<1>>) {
    let weight = equivariant::expand(conv.weight.val(), groups);
    let bias = conv
        .bias
        .as_ref()
        .map(|bias| equivariant::per_channel(bias.val(), groups[1]));
    (weight, bias)
}

/// `conv` as an ordinary convolution with its [`full_weights`].
fn expanded_conv(conv: &Conv2d, groups: [usize; 2]) -> Conv2d {
    let (weight, bias) = full_weights(conv, groups);
    let mut full = conv.clone();
    full.weight = Param::from_tensor(weight);
    full.bias = bias.map(Param::from_tensor);
    full
}

/// The padding on every side that keeps a stride-1 convolution's size (the net's every
/// convolution is padded so).
fn same_padding(conv: &Conv2d) -> usize {
    conv.dilation[0] * (conv.kernel_size[0] - 1) / 2
}

/// `norm` over fields of `group` channels as a norm of every channel.
fn expanded_norm(norm: &BatchNorm, group: usize) -> BatchNorm {
    let [fields] = norm.gamma.dims();
    let device = norm.gamma.device();
    let per_channel = |values: Tensor<1>| equivariant::per_channel(values, group);
    let mut full = BatchNormConfig::new(fields * group)
        .with_epsilon(norm.epsilon)
        .with_momentum(norm.momentum)
        .init(&device);
    full.gamma = Param::from_tensor(per_channel(norm.gamma.val()));
    full.beta = Param::from_tensor(per_channel(norm.beta.val()));
    full.running_mean = RunningState::new(per_channel(norm.running_mean.value()));
    full.running_var = RunningState::new(per_channel(norm.running_var.value()));
    full
}

/// `conv` (its base kernels laid out for `groups`) on `x`, by the fastest route for what
/// the result is for. On the CPU, a net in training (its weights take gradients) goes
/// through [`conv_as_gemm`]; otherwise, and on any other backend (a GPU's, whose
/// convolution kernels and their gradients are burn's own, tuned for it), burn's own
/// `conv2d`.
fn convolve(conv: &Conv2d, groups: [usize; 2], x: Tensor<4>) -> Tensor<4> {
    let training = conv.weight.val().is_require_grad();
    let (weight, bias) = full_weights(conv, groups);
    if training && x.device().without_autodiff() == Device::flex() {
        conv_as_gemm(conv, weight, bias, x)
    } else {
        let options = ConvOptions::new(conv.stride, [same_padding(conv); 2], conv.dilation, 1);
        module::conv2d(x, weight, bias, options)
    }
}

/// `conv`'s shape (square kernel, stride and dilation, padded to keep the size: the net's
/// every convolution) with `weight` and `bias`, as one matrix product of the weights with
/// the input unfolded ([`crate::gemm_conv`]). Forward it equals burn's `conv2d`; backward,
/// its weight gradient is one GEMM over the batch's pixels, where burn's generic
/// `conv2d_weight_backward` runs a convolution whose kernel is the whole output gradient,
/// several times slower at a training step's one or two items, and its input gradient the
/// unfolding's own fold.
fn conv_as_gemm(
    conv: &Conv2d,
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    x: Tensor<4>,
) -> Tensor<4> {
    let [out_channels, _, kernel, _] = weight.dims();
    let taps = Taps {
        kernel,
        stride: conv.stride[0],
        dilation: conv.dilation[0],
        padding: same_padding(conv),
    };
    let mut y = gemm_conv::conv(x, weight, taps);
    if let Some(bias) = bias {
        y = y + bias.reshape([1, out_channels, 1, 1]);
    }
    y
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
mod tests {
    use burn::tensor::Distribution;
    use burn::tensor::activation::relu;

    use super::*;
    use crate::testing::assert_close;

    /// `conv`'s output at `x` and the gradients of `sum(y^2) / 2` (so each output pixel's
    /// gradient is its own value): input, weight, bias.
    fn output_and_gradients(
        conv: &Conv2d,
        x: &Tensor<4>,
        run: fn(&Conv2d, Tensor<4>) -> Tensor<4>,
    ) -> [Vec<f32>; 4] {
        let x = x.clone().require_grad();
        let y = run(conv, x.clone());
        let grads = (y.clone() * y.clone()).sum().mul_scalar(0.5).backward();
        let values = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
        let bias = conv
            .bias
            .as_ref()
            .expect("a bias")
            .val()
            .grad(&grads)
            .unwrap();
        [
            values(y),
            values(x.grad(&grads).unwrap()),
            values(conv.weight.val().grad(&grads).unwrap()),
            bias.into_data().try_to_vec::<f32>().unwrap(),
        ]
    }

    #[test]
    fn a_fresh_head_keeps_the_trunks_and_redraws_the_head() {
        let device = Device::flex();
        let config = QNetConfig {
            context_dilations: vec![1],
            fuse_context: true,
            ..QNetConfig::default()
        };
        let net = PrimitiveNet::new(&config, true, &device);
        let values = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
        let trunk = |net: &PrimitiveNet| {
            [&net.colour, &net.depth, &net.mask, &net.fused]
                .map(|trunk| values(trunk.blocks[0].conv.weight.val()))
        };
        let outputs = |net: &PrimitiveNet| {
            let outcome = net.outcome_out.as_ref().expect("an outcome head");
            [&net.head_out, outcome].map(|conv| values(conv.weight.val()))
        };
        let before = (trunk(&net), outputs(&net));
        let mut fresh = net.clone();
        fresh.fresh_head(&config, &device);
        assert_eq!(trunk(&fresh), before.0);
        for (after, before) in outputs(&fresh).iter().zip(&before.1) {
            assert_ne!(after, before);
        }
        let x = |channels| Tensor::<4>::ones([1, channels, 16, 16], &device);
        assert_eq!(fresh.forward(x(3), x(1), x(1)).dims(), [1, 1, 4, 4]);
        let both = fresh.forward_with_outcome(x(3), x(1), x(1));
        assert_eq!(both.dims(), [1, 2, 4, 4]);
        assert_eq!(
            values(both.slice([0..1, 0..1])),
            values(fresh.forward(x(3), x(1), x(1)))
        );
    }

    #[test]
    fn an_equivariant_net_turns_its_maps_with_its_input_and_shifts_their_angles() {
        // Channel g scores the action g quarter turns on: the input turned a quarter turn
        // gives each map turned, one angle on. Exact on sides that stay odd down the
        // strides (17, 9, 5), in training (batch statistics shared within a field) and
        // frozen, and the same function as the net laid out in full.
        let config = QNetConfig {
            trunk_widths: vec![4, 8],
            context_dilations: vec![1],
            head_width: 8,
            rotation_equivariant: true,
            ..QNetConfig::default()
        };
        let device = Device::flex();
        let net = PrimitiveNet::new(&config, false, &device);
        let input = |c| Tensor::<4>::random([2, c, 17, 17], Distribution::Default, &device);
        let planes = [input(3), input(1), input(1)];
        let turn = crate::equivariant::quarter_turn::<4, Float>;
        let values = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
        let forward = |net: &PrimitiveNet, turned: bool| {
            let on = net.devices()[0].clone();
            let [c, d, m] = planes.clone().map(|x| {
                let x = x.to_device(&on);
                if turned { turn(x) } else { x }
            });
            net.forward(c, d, m)
        };
        let check = |net: &PrimitiveNet, what: &str| {
            let y = forward(net, false);
            assert_eq!(y.dims(), [2, 4, 5, 5]);
            let expected = turn(y).roll_dim(1, 1);
            assert_close(&values(forward(net, true)), &values(expected), 1e-4, what);
        };
        let training = net.to_device(&device.autodiff()).train();
        check(&training, "in training");
        let frozen = training.valid();
        check(&frozen, "frozen");
        let ordinary = frozen.expanded();
        assert_eq!(ordinary.group(), 1);
        assert_eq!(
            [ordinary.angles_per_pass(), frozen.angles_per_pass()],
            [4, 4]
        );
        assert_close(
            &values(forward(&ordinary, false)),
            &values(forward(&frozen, false)),
            1e-5,
            "laid out in full",
        );
    }

    #[test]
    fn the_gemm_convolution_and_its_gradients_equal_burns_conv2d() {
        let device = Device::flex().autodiff();
        for (stride, dilation) in [(2, 1), (1, 1), (1, 2)] {
            let mut conv = ConvBlock::new([3, 5], stride, dilation, [1, 1], &device).conv;
            // A block's convolution has none, the head's last has one: test with one.
            let bias = Tensor::<1>::random([5], Distribution::Default, &device);
            conv.bias = Some(burn::module::Param::from_tensor(bias));
            let x = Tensor::<4>::random([2, 3, 12, 12], Distribution::Default, &device);
            let ours = output_and_gradients(&conv, &x, |conv, x| {
                let bias = conv.bias.as_ref().map(|bias| bias.val());
                conv_as_gemm(conv, conv.weight.val(), bias, x)
            });
            let burns = output_and_gradients(&conv, &x, |conv, x| conv.forward(x));
            for (what, (a, b)) in ["output", "input grad", "weight grad", "bias grad"]
                .iter()
                .zip(ours.iter().zip(&burns))
            {
                let what = format!("stride {stride}, dilation {dilation}: {what}");
                assert_close(a, b, 1e-5, &what);
            }
        }
    }

    #[test]
    fn batch_norm_and_relu_in_training_equal_burns_output_gradients_and_running_statistics() {
        let device = Device::flex().autodiff();
        let x = Tensor::<4>::random([3, 5, 7, 7], Distribution::Default, &device).mul_scalar(3.0);
        let run = |ours: bool| {
            let norm = BatchNormConfig::new(5).init(&device);
            let x = x.clone().require_grad();
            let y = if ours {
                batch_norm::forward_relu(&norm, x.clone())
            } else {
                relu(norm.forward(x.clone()))
            };
            // A loss whose gradient differs per pixel, so every term of the backward counts,
            // and is not zero where the ReLU cut the value, so its mask counts too.
            let grads = (y.clone() * (y.clone() + x.clone().detach()))
                .sum()
                .backward();
            let values4 = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
            let values1 = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap();
            [
                values4(y),
                values4(x.grad(&grads).unwrap()),
                values1(norm.gamma.val().grad(&grads).unwrap()),
                values1(norm.beta.val().grad(&grads).unwrap()),
                values1(norm.running_mean.value_sync()),
                values1(norm.running_var.value_sync()),
            ]
        };
        let (ours, burns) = (run(true), run(false));
        let parts = [
            "output",
            "input grad",
            "gamma grad",
            "beta grad",
            "running mean",
            "running var",
        ];
        for ((what, a), b) in parts.iter().zip(&ours).zip(&burns) {
            assert_close(a, b, 1e-4, what);
        }
    }
}
