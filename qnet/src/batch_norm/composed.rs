//! The operation composed from burn's own: each per-channel sum one reduction over the other
//! dimensions, which a GPU backend runs over the activation as it lies (burn's generic
//! `batch_norm_train` and its backward first copy it with the channels moved to the front,
//! for each of four sums), and the rest element-wise. On a GPU the normalisation is this
//! one (element-wise, burn's fusion joins it with its neighbours), the statistics and the
//! gradients where the kernels of `cube` do not take the input (not f32, or its planes not
//! each one run of values); on the CPU it is the reference the loops are tested against.

use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Scalar, TensorMetadata};
use burn::tensor::Shape;

use super::Statistics;

/// Values per channel of a tensor of `shape`: its elements over its channels.
fn count(shape: &Shape) -> usize {
    shape.num_elements() / shape[1]
}

/// `[c]` values shaped to broadcast over `x`'s channels: `[1, c, 1, ...]`.
fn per_channel<B: Backend>(values: FloatTensor<B>, x: &FloatTensor<B>) -> FloatTensor<B> {
    let mut shape = vec![1; x.shape().num_dims()];
    shape[1] = x.shape()[1];
    B::float_reshape(values, shape.into())
}

/// `[1, c, 1, ...]` values as `[c]`.
fn flat<B: Backend>(values: FloatTensor<B>) -> FloatTensor<B> {
    let c = values.shape().num_elements();
    B::float_reshape(values, [c].into())
}

/// The sum of each channel of `x`, `[1, c, 1, ...]`.
fn channel_sums<B: Backend>(x: FloatTensor<B>) -> FloatTensor<B> {
    let others: Vec<usize> = (0..x.shape().num_dims()).filter(|&d| d != 1).collect();
    B::float_sum_dims(x, &others)
}

/// `1 / sqrt(variance + epsilon)`, as `variance` is shaped.
fn inverse_std<B: Backend>(variance: FloatTensor<B>, epsilon: f64) -> FloatTensor<B> {
    let shifted = B::float_add_scalar(variance, Scalar::Float(epsilon));
    B::float_recip(B::float_sqrt(shifted))
}

/// Mean, then biased variance about it (two passes, as the CPU's loops).
pub(super) fn statistics<B: Backend>(x: FloatTensor<B>) -> (FloatTensor<B>, FloatTensor<B>) {
    // The mean is scaled after its sum: burn's fusion does not join element-wise
    // operations with a reduction over several dimensions, so a scaling just before the
    // sum ran as a kernel of its own, where after it it joins the next kernel. The
    // variance's share is taken in the kernel that squares, before its sum.
    let share = Scalar::Float(1.0 / count(&x.shape()) as f64);
    let mean = B::float_mul_scalar(channel_sums::<B>(x.clone()), share);
    let centred = B::float_sub(x, mean.clone());
    let squares = B::float_mul(centred.clone(), centred);
    let variance = channel_sums::<B>(B::float_mul_scalar(squares, share));
    (flat::<B>(mean), flat::<B>(variance))
}

/// The batch's statistics with the running ones moved toward them, as burn's `BatchNorm`
/// moves them: `running (1 - momentum) + batch momentum`.
pub(super) fn with_running<B: Backend>(
    (mean, variance): (FloatTensor<B>, FloatTensor<B>),
    [running_mean, running_variance]: [FloatTensor<B>; 2],
    momentum: f64,
) -> Statistics<B> {
    let moved = |running, batch: &FloatTensor<B>| {
        B::float_add(
            B::float_mul_scalar(running, Scalar::Float(1.0 - momentum)),
            B::float_mul_scalar(batch.clone(), Scalar::Float(momentum)),
        )
    };
    let running_mean = moved(running_mean, &mean);
    let running_variance = moved(running_variance, &variance);
    (mean, variance, running_mean, running_variance)
}

/// The normalisation with the batch's statistics and the ReLU, as one affine map per
/// channel: `relu(x * scale + shift)`, `scale = gamma / std` and `shift = beta - mean
/// scale` formed on the `[c]` values first.
pub(super) fn train<B: Backend>(
    x: FloatTensor<B>,
    gamma: FloatTensor<B>,
    beta: FloatTensor<B>,
    mean: FloatTensor<B>,
    variance: FloatTensor<B>,
    epsilon: f64,
) -> FloatTensor<B> {
    // Every `[c]` value shaped first: burn's fusion does not join a reshape with the
    // element-wise operations around it, and arithmetic on the `[c]` values between
    // reshapes ran as kernels of their own.
    let [gamma, beta, mean, variance] =
        [gamma, beta, mean, variance].map(|values| per_channel::<B>(values, &x));
    let scale = B::float_mul(gamma, inverse_std::<B>(variance, epsilon));
    let shift = B::float_sub(beta, B::float_mul(mean, scale.clone()));
    B::relu(B::float_add(B::float_mul(x, scale), shift))
}

/// With `x_hat` the normalised input and `dy` the output's gradient through the ReLU:
/// beta's gradient `sum(dy)`, gamma's `sum(dy x_hat)`, and the input's
/// `gamma / std / n (n dy - sum(dy) - x_hat sum(dy x_hat))`, per channel.
pub(super) fn grads<B: Backend>(
    x: FloatTensor<B>,
    gamma: FloatTensor<B>,
    mean: FloatTensor<B>,
    variance: FloatTensor<B>,
    epsilon: f64,
    output: FloatTensor<B>,
    grad: FloatTensor<B>,
) -> (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>) {
    let n = count(&x.shape()) as f64;
    let inv_std = inverse_std::<B>(per_channel::<B>(variance, &x), epsilon);
    let mean = per_channel::<B>(mean, &x);
    let gamma = per_channel::<B>(gamma, &x);
    let dy = B::relu_backward(output, grad);
    let x_hat = B::float_mul(B::float_sub(x, mean), inv_std.clone());
    // Both sums' operands formed before either sum: an element-wise operation issued
    // between two reductions runs as a kernel of its own.
    let dy_x_hat = B::float_mul(dy.clone(), x_hat.clone());
    let sum_dy = channel_sums::<B>(dy.clone());
    let sum_dy_x_hat = channel_sums::<B>(dy_x_hat);
    let factor = B::float_div_scalar(B::float_mul(gamma, inv_std), Scalar::Float(n));
    let inner = B::float_sub(
        B::float_sub(B::float_mul_scalar(dy, Scalar::Float(n)), sum_dy.clone()),
        B::float_mul(x_hat, sum_dy_x_hat.clone()),
    );
    let x_grad = B::float_mul(factor, inner);
    (x_grad, flat::<B>(sum_dy_x_hat), flat::<B>(sum_dy))
}
