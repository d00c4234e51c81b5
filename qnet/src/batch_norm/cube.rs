//! The statistics and the gradients on a GPU (CubeCL), each one kernel: a cube's threads
//! run over the values of a channel (or of a few channels side by side), sum them in shared
//! memory, and go over them again with the sums (the variance about the mean; the input's
//! gradient). Composed from burn's operations, the statistics took two reductions and an
//! element-wise kernel between them, and the gradients an element-wise kernel, two
//! reductions and another element-wise one (results/gpu.md, "The batch norm in two
//! kernels"). The normalisation itself stays composed: element-wise, it fuses with what is
//! around it.
//!
//! Neighbouring threads read neighbouring values: along a plane where the channels are
//! planes (`[n, c, h, w]` in memory), across the channels where they lie last (as a
//! convolution hands its output over, `[n, h, w, c]` read through strides). The input's
//! gradient is laid out as the input.

use burn::backend::wgpu::{CubeBackend, CubeTensor};
use burn::cubecl;
use burn::tensor::Shape;
use cubecl::prelude::*;
use cubecl::{CubeCount, CubeDim};

use super::{NormBackend, Statistics, composed};
use crate::cube_outputs::{all_f32, empty, empty_like};

/// Threads a cube, a power of two.
const THREADS: usize = 256;

/// `(channel, first, step)`: the channel a thread sums, and which of each of its planes'
/// values it takes, every `step`-th from the `first`. A cube a channel, every thread along
/// the planes; or, `channels_last`, a channel a column of threads (`CUBE_DIM_X` channels a
/// cube), its rows along the planes.
#[cube]
fn thread_place(#[comptime] channels_last: bool) -> (usize, usize, usize) {
    if channels_last {
        (
            (CUBE_POS_X * CUBE_DIM_X + UNIT_POS_X) as usize,
            UNIT_POS_Y as usize,
            CUBE_DIM_Y as usize,
        )
    } else {
        (CUBE_POS_X as usize, UNIT_POS as usize, CUBE_DIM as usize)
    }
}

/// The sum of `value` over the threads of the cube that sum the same channel, in each of
/// them. `partial` holds a value a thread; it is free again when this returns.
#[cube]
fn channel_sum(value: f32, partial: &mut Shared<[f32]>, #[comptime] channels_last: bool) -> f32 {
    let unit = UNIT_POS as usize;
    // A channel's threads are a column of the cube (`CUBE_DIM_X` apart), or all of it.
    let mut lanes = 1usize;
    if channels_last {
        lanes = CUBE_DIM_X as usize;
    }
    partial[unit] = value;
    sync_cube();
    let mut half = CUBE_DIM as usize / 2;
    while half >= lanes {
        if unit < half {
            let other = partial[unit + half];
            partial[unit] += other;
        }
        sync_cube();
        half /= 2;
    }
    let sum = partial[unit % lanes];
    sync_cube();
    sum
}

/// Where the plane of channel `channel` of item `item` starts in `t` (`[n, c, h, w]`).
#[cube]
fn plane_start(t: &Tensor<f32>, item: usize, channel: usize) -> usize {
    item * t.stride(0) + channel * t.stride(1)
}

/// The sum of `v - centre`, or of its square, over a thread's share of the values `v` of
/// channel `channel` of `x`: every `step`-th value of each plane from its `first`. A thread
/// past the last channel sums nothing (but takes its part in the cube's sums).
#[cube]
fn share_sum(
    x: &Tensor<f32>,
    channel: usize,
    first: usize,
    step: usize,
    centre: f32,
    #[comptime] squared: bool,
) -> f32 {
    let (plane, along) = (x.shape(2) * x.shape(3), x.stride(3));
    let mut sum = 0.0f32;
    if channel < x.shape(1) {
        for item in 0..x.shape(0) {
            let start = plane_start(x, item, channel);
            let mut at = first;
            while at < plane {
                let d = x[start + at * along] - centre;
                if squared {
                    sum += d * d;
                } else {
                    sum += d;
                }
                at += step;
            }
        }
    }
    sum
}

/// The output's gradient through the ReLU, `dy`, and the normalised input, `x_hat`, at the
/// given places of `output`, `grad` and `x`.
#[cube]
#[allow(clippy::too_many_arguments)]
fn dy_and_x_hat(
    x: &Tensor<f32>,
    output: &Tensor<f32>,
    grad: &Tensor<f32>,
    at_x: usize,
    at_output: usize,
    at_grad: usize,
    centre: f32,
    inv_std: f32,
) -> (f32, f32) {
    let relu = output[at_output] > 0.0;
    (
        select(relu, grad[at_grad], 0.0f32),
        (x[at_x] - centre) * inv_std,
    )
}

/// The mean and biased variance of each channel of `x` (`[n, c, h, w]`, its planes
/// `x.stride(3)` a value), in two passes over its values, and the running mean and variance
/// moved toward them (`running keep + batch take`).
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn norm_statistics_kernel(
    x: &Tensor<f32>,
    running_mean: &Tensor<f32>,
    running_variance: &Tensor<f32>,
    mean: &mut Tensor<f32>,
    variance: &mut Tensor<f32>,
    running_mean_out: &mut Tensor<f32>,
    running_variance_out: &mut Tensor<f32>,
    keep: f32,
    take: f32,
    #[comptime] channels_last: bool,
    #[comptime] threads: usize,
) {
    let (channel, first, step) = thread_place(channels_last);
    let mut partial = Shared::new_slice(threads);
    let share = 1.0 / f32::cast_from(x.shape(0) * x.shape(2) * x.shape(3));
    let sum = share_sum(x, channel, first, step, 0.0, false);
    let centre = channel_sum(sum, &mut partial, channels_last) * share;
    let squares = share_sum(x, channel, first, step, centre, true);
    let spread = channel_sum(squares, &mut partial, channels_last) * share;
    if channel < x.shape(1) && first == 0 {
        mean[channel] = centre;
        variance[channel] = spread;
        running_mean_out[channel] =
            running_mean[channel * running_mean.stride(0)] * keep + centre * take;
        running_variance_out[channel] =
            running_variance[channel * running_variance.stride(0)] * keep + spread * take;
    }
}

/// The gradients of each channel: beta's `sum(dy)`, gamma's `sum(dy x_hat)` (one pass),
/// then the input's `gamma / std / m (m dy - sum(dy) - x_hat sum(dy x_hat))` (a second),
/// with `dy` the output's gradient through the ReLU, `x_hat` the normalised input and `m`
/// the values a channel. Every `[n, c, h, w]` tensor's planes are `stride(3)` a value.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn norm_grads_kernel(
    x: &Tensor<f32>,
    gamma: &Tensor<f32>,
    mean: &Tensor<f32>,
    variance: &Tensor<f32>,
    output: &Tensor<f32>,
    grad: &Tensor<f32>,
    x_grad: &mut Tensor<f32>,
    gamma_grad: &mut Tensor<f32>,
    beta_grad: &mut Tensor<f32>,
    epsilon: f32,
    #[comptime] channels_last: bool,
    #[comptime] threads: usize,
) {
    let (channel, first, step) = thread_place(channels_last);
    let (items, plane) = (x.shape(0), x.shape(2) * x.shape(3));
    let live = channel < x.shape(1);
    let mut partial = Shared::new_slice(threads);
    let mut centre = 0.0f32;
    let mut inv_std = 0.0f32;
    let mut scale = 0.0f32;
    if live {
        centre = mean[channel * mean.stride(0)];
        inv_std = 1.0 / f32::sqrt(variance[channel * variance.stride(0)] + epsilon);
        scale = gamma[channel * gamma.stride(0)];
    }
    let along = (
        x.stride(3),
        output.stride(3),
        grad.stride(3),
        x_grad.stride(3),
    );

    let mut sum_dy = 0.0f32;
    let mut sum_dy_x_hat = 0.0f32;
    for item in 0..items {
        let at_x = plane_start(x, item, channel);
        let at_output = plane_start(output, item, channel);
        let at_grad = plane_start(grad, item, channel);
        let mut at = first;
        while live && at < plane {
            let (dy, x_hat) = dy_and_x_hat(
                x,
                output,
                grad,
                at_x + at * along.0,
                at_output + at * along.1,
                at_grad + at * along.2,
                centre,
                inv_std,
            );
            sum_dy += dy;
            sum_dy_x_hat += dy * x_hat;
            at += step;
        }
    }
    let sum_dy = channel_sum(sum_dy, &mut partial, channels_last);
    let sum_dy_x_hat = channel_sum(sum_dy_x_hat, &mut partial, channels_last);
    if live && first == 0 {
        gamma_grad[channel] = sum_dy_x_hat;
        beta_grad[channel] = sum_dy;
    }

    let m = f32::cast_from(items * plane);
    let factor = scale * inv_std / m;
    for item in 0..items {
        let at_x = plane_start(x, item, channel);
        let at_output = plane_start(output, item, channel);
        let at_grad = plane_start(grad, item, channel);
        // Written, so its strides are read here (a helper takes tensors it only reads).
        let at_x_grad = item * x_grad.stride(0) + channel * x_grad.stride(1);
        let mut at = first;
        while live && at < plane {
            let (dy, x_hat) = dy_and_x_hat(
                x,
                output,
                grad,
                at_x + at * along.0,
                at_output + at * along.1,
                at_grad + at * along.2,
                centre,
                inv_std,
            );
            x_grad[at_x_grad + at * along.3] = factor * (dy * m - sum_dy - x_hat * sum_dy_x_hat);
            at += step;
        }
    }
}

/// Whether `t` (`[n, c, h, w]`) holds each plane as one run of values, `stride(3)` apart
/// (its rows follow one another), as the kernels read it.
fn planes_in_runs(t: &CubeTensor) -> bool {
    let (shape, strides) = (t.meta.shape(), t.meta.strides());
    shape.num_dims() == 4 && (shape[2] == 1 || strides[2] == shape[3] * strides[3])
}

/// The kernels' cubes and whether they go across the channels: where `x`'s channels lie
/// last, `CUBE_DIM_X` channels a cube (at most 32, the power of two that covers them) by
/// as many rows as make [`THREADS`]; else a cube a channel.
fn launch_shape(x: &CubeTensor) -> (CubeCount, CubeDim, bool) {
    let (shape, strides) = (x.meta.shape(), x.meta.strides());
    let channels = shape[1];
    if strides[1] < strides[3] {
        let across = channels.next_power_of_two().min(32);
        let cubes = channels.div_ceil(across);
        let cube_dim = CubeDim::new_2d(across as u32, (THREADS / across) as u32);
        (CubeCount::Static(cubes as u32, 1, 1), cube_dim, true)
    } else {
        let cube_dim = CubeDim::new_1d(THREADS as u32);
        (CubeCount::Static(channels as u32, 1, 1), cube_dim, false)
    }
}

impl NormBackend for CubeBackend {
    fn norm_statistics(
        x: CubeTensor,
        running_mean: CubeTensor,
        running_variance: CubeTensor,
        momentum: f64,
    ) -> Statistics<Self> {
        let running = [running_mean, running_variance];
        if !all_f32([&x, &running[0], &running[1]]) || !planes_in_runs(&x) {
            let statistics = composed::statistics::<Self>(x);
            return composed::with_running::<Self>(statistics, running, momentum);
        }
        let (cubes, cube_dim, channels_last) = launch_shape(&x);
        let channels = Shape::from([x.meta.shape()[1]]);
        let [mean, variance, running_mean_out, running_variance_out] =
            [(); 4].map(|_| empty(&x, channels.clone()));
        let client = x.client.clone();
        let [running_mean, running_variance] = running;
        norm_statistics_kernel::launch(
            &client,
            cubes,
            cube_dim,
            x.into_tensor_arg(),
            running_mean.into_tensor_arg(),
            running_variance.into_tensor_arg(),
            mean.clone().into_tensor_arg(),
            variance.clone().into_tensor_arg(),
            running_mean_out.clone().into_tensor_arg(),
            running_variance_out.clone().into_tensor_arg(),
            (1.0 - momentum) as f32,
            momentum as f32,
            channels_last,
            THREADS,
        );
        (mean, variance, running_mean_out, running_variance_out)
    }

    fn norm_relu_train_grads(
        x: CubeTensor,
        gamma: CubeTensor,
        mean: CubeTensor,
        variance: CubeTensor,
        epsilon: f64,
        output: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor, CubeTensor) {
        // (The input's gradient, laid out as `x` or contiguously, has its planes in runs
        // whenever `x` has.)
        if ![&x, &output, &grad].iter().all(|t| planes_in_runs(t))
            || !all_f32([&x, &gamma, &mean, &variance, &output, &grad])
        {
            return composed::grads::<Self>(x, gamma, mean, variance, epsilon, output, grad);
        }
        let (cubes, cube_dim, channels_last) = launch_shape(&x);
        let x_grad = empty_like(&x);
        let [gamma_grad, beta_grad] = [
            empty(&x, gamma.meta.shape().clone()),
            empty(&x, gamma.meta.shape().clone()),
        ];
        let client = x.client.clone();
        norm_grads_kernel::launch(
            &client,
            cubes,
            cube_dim,
            x.into_tensor_arg(),
            gamma.into_tensor_arg(),
            mean.into_tensor_arg(),
            variance.into_tensor_arg(),
            output.into_tensor_arg(),
            grad.into_tensor_arg(),
            x_grad.clone().into_tensor_arg(),
            gamma_grad.clone().into_tensor_arg(),
            beta_grad.clone().into_tensor_arg(),
            epsilon as f32,
            channels_last,
            THREADS,
        );
        (x_grad, gamma_grad, beta_grad)
    }
}
