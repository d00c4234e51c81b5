//! How the nets' convolutions and batch norms run (the CPU's own convolution, the batch
//! norm with its ReLU), and their expanded forms, one channel a rotation.

use burn::module::{Param, RunningState};
use burn::nn::conv::Conv2d;
use burn::nn::{BatchNorm, BatchNormConfig};
use burn::prelude::*;
use burn::tensor::module;
use burn::tensor::ops::ConvOptions;

use crate::batch_norm;
use crate::equivariant;
use crate::gemm_conv::{self, Taps};

/// `norm` and a ReLU over `x` whose fields have `group` channels each, sharing a field's
/// statistics.
pub(super) fn norm_relu(norm: &BatchNorm, group: usize, x: Tensor<4>) -> Tensor<4> {
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
pub(super) fn full_weights(conv: &Conv2d, groups: [usize; 2]) -> (Tensor<4>, Option<Tensor<1>>) {
    let weight = equivariant::expand(conv.weight.val(), groups);
    let bias = conv
        .bias
        .as_ref()
        .map(|bias| equivariant::per_channel(bias.val(), groups[1]));
    (weight, bias)
}

/// `conv` as an ordinary convolution with its [`full_weights`].
pub(super) fn expanded_conv(conv: &Conv2d, groups: [usize; 2]) -> Conv2d {
    let (weight, bias) = full_weights(conv, groups);
    let mut full = conv.clone();
    full.weight = Param::from_tensor(weight);
    full.bias = bias.map(Param::from_tensor);
    full
}

/// The padding on every side that keeps a stride-1 convolution's size (the net's every
/// convolution is padded so).
pub(super) fn same_padding(conv: &Conv2d) -> usize {
    conv.dilation[0] * (conv.kernel_size[0] - 1) / 2
}

/// `norm` over fields of `group` channels as a norm of every channel.
pub(super) fn expanded_norm(norm: &BatchNorm, group: usize) -> BatchNorm {
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
pub(super) fn convolve(conv: &Conv2d, groups: [usize; 2], x: Tensor<4>) -> Tensor<4> {
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
pub(super) fn conv_as_gemm(
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
