//! Batch norm and the ReLU after it, in training, as an operation of its own: a quarter of a
//! one-grasp training step went to burn's generic `batch_norm_train` and its backward, which
//! move every channel to the front (a transposed copy of the activation) for each of their
//! statistics, and the ReLU then made and read another copy each way. On the CPU backend
//! the statistics, the normalisation with its ReLU and the three gradients are plain loops
//! over each channel's planes; elsewhere (wgpu) burn's own operations, composed so that each
//! statistic is one sum over every dimension but the channels' (no transposed copy) and the
//! rest element-wise, which burn's fusion joins into few kernels. Every batch norm of the
//! nets is followed by a ReLU. The module keeps burn's [`BatchNorm`] (its parameters,
//! running statistics and their update), so checkpoints and the inference path do not
//! change.

use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, Flex, Scalar, TensorMetadata, backend_extension,
};
use burn::nn::BatchNorm;
use burn::prelude::*;
use burn::tensor::activation::relu;
use burn::tensor::{DType, Shape};

use rayon::prelude::*;

use crate::fresh::planes_from;
use crate::gemm_conv::flex_tensor;

/// The operation on a backend: inputs `[n, c, ...]`, per-channel `gamma` and `beta`, and
/// the batch's mean and biased variance per channel (`[c]` each), which
/// [`NormBackend::norm_statistics`] computes once per pass. (Each a tensor of its own: a
/// view into one stacked buffer cost a device a copy and a slice per use.)
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "wgpu"))]
pub trait NormBackend: Backend {
    /// The batch mean and biased variance of each channel, `[c]` each; no gradient.
    fn norm_statistics(x: FloatTensor<Self>) -> (FloatTensor<Self>, FloatTensor<Self>) {
        composed::statistics::<Self>(x)
    }

    /// `relu((x - mean) / sqrt(variance + epsilon) * gamma + beta)` with the batch's
    /// statistics. Its backward differentiates through the statistics as functions of `x`.
    fn norm_relu_train(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        mean: FloatTensor<Self>,
        variance: FloatTensor<Self>,
        epsilon: f64,
    ) -> FloatTensor<Self> {
        composed::train::<Self>(x, gamma, beta, mean, variance, epsilon)
    }

    /// The gradients of [`NormBackend::norm_relu_train`], whose `output` it was: input,
    /// gamma and beta. (Each a tensor of its own, as the statistics.)
    fn norm_relu_train_grads(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        mean: FloatTensor<Self>,
        variance: FloatTensor<Self>,
        epsilon: f64,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        composed::grads::<Self>(x, gamma, mean, variance, epsilon, output, grad)
    }
}

/// One channel's values across the batch: `x` as `[n, c, m]`, channel `k`.
fn channel(x: &[f32], c: usize, m: usize, k: usize) -> impl Iterator<Item = &[f32]> {
    x.chunks_exact(c * m)
        .map(move |item| &item[k * m..(k + 1) * m])
}

/// Mean and biased variance of one channel (two passes).
fn moments(x: &[f32], c: usize, m: usize, k: usize) -> (f32, f32) {
    let count = (x.len() / c) as f64;
    let mean = channel(x, c, m, k)
        .map(|p| lane_sum(p, p, |v, _| v))
        .sum::<f64>()
        / count;
    let centre = mean as f32;
    let variance = channel(x, c, m, k)
        .map(|p| lane_sum(p, p, |v, _| (v - centre) * (v - centre)))
        .sum::<f64>()
        / count;
    (mean as f32, variance as f32)
}

/// The sum of `f(a[i], b[i])` over two slices of one length. Sixteen f32 lanes, summed in
/// f64 at the end, let the compiler vectorise the loop (a single running sum cannot be
/// reordered) while each lane adds only a plane's sixteenth.
fn lane_sum(a: &[f32], b: &[f32], f: impl Fn(f32, f32) -> f32) -> f64 {
    const LANES: usize = 16;
    let mut lanes = [0f32; LANES];
    let (a_chunks, b_chunks) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f64 = (a_chunks.remainder().iter())
        .zip(b_chunks.remainder())
        .map(|(&a, &b)| f(a, b) as f64)
        .sum();
    for (a, b) in a_chunks.zip(b_chunks) {
        for lane in 0..LANES {
            lanes[lane] += f(a[lane], b[lane]);
        }
    }
    lanes.iter().map(|&v| v as f64).sum::<f64>() + tail
}

/// Plane `p` of `m` values of `values`.
fn plane(values: &[f32], m: usize, p: usize) -> &[f32] {
    &values[p * m..(p + 1) * m]
}

/// The channels `c` and the values per plane `m` of an f32 CPU tensor `[n, c, ...]`, or
/// `None` to fall back to the composed operation.
fn layout(x: &FloatTensor<Flex>) -> Option<[usize; 2]> {
    let shape = x.shape();
    (x.dtype() == DType::F32 && shape.num_dims() >= 2).then(|| {
        let [n, c] = [shape[0], shape[1]];
        [c, shape.num_elements() / (n * c).max(1)]
    })
}

impl NormBackend for Flex {
    fn norm_statistics(x: FloatTensor<Self>) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let Some([c, m]) = layout(&x) else {
            return composed::statistics::<Self>(x);
        };
        let x = x.to_contiguous();
        let values: &[f32] = x.storage();
        let (mean, variance): (Vec<f32>, Vec<f32>) = (0..c)
            .into_par_iter()
            .map(|k| moments(values, c, m, k))
            .unzip();
        (flex_tensor(mean, vec![c]), flex_tensor(variance, vec![c]))
    }

    fn norm_relu_train(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        mean: FloatTensor<Self>,
        variance: FloatTensor<Self>,
        epsilon: f64,
    ) -> FloatTensor<Self> {
        let Some([c, m]) = layout(&x) else {
            return composed::train::<Self>(x, gamma, beta, mean, variance, epsilon);
        };
        let shape = x.shape().to_vec();
        let tensors = [x, gamma, beta, mean, variance].map(|t| t.to_contiguous());
        let [values, gamma, beta, mean, variance]: [&[f32]; 5] =
            tensors.each_ref().map(|t| t.storage());
        let affine: Vec<(f32, f32)> = (0..c)
            .map(|k| {
                let scale = gamma[k] / (variance[k] + epsilon as f32).sqrt();
                (scale, beta[k] - mean[k] * scale)
            })
            .collect();
        let out = planes_from(values.len(), m, |p, slots| {
            let (scale, shift) = affine[p % c];
            for (slot, &x) in slots.iter_mut().zip(plane(values, m, p)) {
                slot.write((x * scale + shift).max(0.0));
            }
        });
        flex_tensor(out, shape)
    }

    fn norm_relu_train_grads(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        mean: FloatTensor<Self>,
        variance: FloatTensor<Self>,
        epsilon: f64,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let Some([c, m]) = layout(&x) else {
            return composed::grads::<Self>(x, gamma, mean, variance, epsilon, output, grad);
        };
        let shape = x.shape().to_vec();
        let tensors = [x, gamma, mean, variance, output, grad].map(|t| t.to_contiguous());
        let [values, gamma, mean, variance, y, grad]: [&[f32]; 6] =
            tensors.each_ref().map(|t| t.storage());
        // The gradient through the ReLU: none where it cut the value to 0.
        let mut out = planes_from(values.len(), m, |p, slots| {
            for ((slot, &y), &g) in slots.iter_mut().zip(plane(y, m, p)).zip(plane(grad, m, p)) {
                slot.write(if y > 0.0 { g } else { 0.0 });
            }
        });
        let dy = out.as_slice();
        let count = (values.len() / c) as f32;
        // Per channel: mean, 1 / std, sum(dy), sum(dy x_hat).
        let sums: Vec<[f32; 4]> = (0..c)
            .into_par_iter()
            .map(|k| {
                let (mean, variance) = (mean[k], variance[k]);
                let inv_std = 1.0 / (variance + epsilon as f32).sqrt();
                let (mut sum_dy, mut sum_dy_xhat) = (0f64, 0f64);
                for (x, dy) in channel(values, c, m, k).zip(channel(dy, c, m, k)) {
                    sum_dy += lane_sum(dy, dy, |dy, _| dy);
                    sum_dy_xhat += lane_sum(x, dy, |x, dy| dy * (x - mean) * inv_std);
                }
                [mean, inv_std, sum_dy as f32, sum_dy_xhat as f32]
            })
            .collect();
        // The input's gradient, written over the ReLU's (each value read once, first).
        out.par_chunks_mut(m)
            .zip(values.par_chunks(m))
            .enumerate()
            .for_each(|(plane, (g, x))| {
                let k = plane % c;
                let [mean, inv_std, sum_dy, sum_dy_xhat] = sums[k];
                let factor = gamma[k] * inv_std / count;
                for (g, &x) in g.iter_mut().zip(x) {
                    let x_hat = (x - mean) * inv_std;
                    *g = factor * (count * *g - sum_dy - x_hat * sum_dy_xhat);
                }
            });
        let parameter = |i: usize| flex_tensor(sums.iter().map(|s| s[i]).collect(), vec![c]);
        (flex_tensor(out, shape), parameter(3), parameter(2))
    }
}

/// The operation composed from burn's own, for every backend: each per-channel sum one
/// reduction over the other dimensions, which a GPU backend runs over the activation as it
/// lies (burn's generic `batch_norm_train` and its backward first copy it with the channels
/// moved to the front, for each of four sums), and the rest element-wise.
mod composed {
    use super::*;

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

    /// `1 / sqrt(variance + epsilon)`, `[1, c, 1, ...]` for `x`.
    fn inverse_std<B: Backend>(
        variance: FloatTensor<B>,
        epsilon: f64,
        x: &FloatTensor<B>,
    ) -> FloatTensor<B> {
        let shifted = B::float_add_scalar(variance, Scalar::Float(epsilon));
        per_channel::<B>(B::float_recip(B::float_sqrt(shifted)), x)
    }

    /// Mean, then biased variance about it (two passes, as the CPU's loops).
    pub fn statistics<B: Backend>(x: FloatTensor<B>) -> (FloatTensor<B>, FloatTensor<B>) {
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

    /// The normalisation with the batch's statistics and the ReLU, as one affine map per
    /// channel: `relu(x * scale + shift)`, `scale = gamma / std` and `shift = beta - mean
    /// scale` formed on the `[c]` values first.
    pub fn train<B: Backend>(
        x: FloatTensor<B>,
        gamma: FloatTensor<B>,
        beta: FloatTensor<B>,
        mean: FloatTensor<B>,
        variance: FloatTensor<B>,
        epsilon: f64,
    ) -> FloatTensor<B> {
        let scale = B::float_mul(
            per_channel::<B>(gamma, &x),
            inverse_std::<B>(variance, epsilon, &x),
        );
        let shift = B::float_sub(
            per_channel::<B>(beta, &x),
            B::float_mul(per_channel::<B>(mean, &x), scale.clone()),
        );
        B::relu(B::float_add(B::float_mul(x, scale), shift))
    }

    /// With `x_hat` the normalised input and `dy` the output's gradient through the ReLU:
    /// beta's gradient `sum(dy)`, gamma's `sum(dy x_hat)`, and the input's
    /// `gamma / std / n (n dy - sum(dy) - x_hat sum(dy x_hat))`, per channel.
    pub fn grads<B: Backend>(
        x: FloatTensor<B>,
        gamma: FloatTensor<B>,
        mean: FloatTensor<B>,
        variance: FloatTensor<B>,
        epsilon: f64,
        output: FloatTensor<B>,
        grad: FloatTensor<B>,
    ) -> (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>) {
        let n = count(&x.shape()) as f64;
        let inv_std = inverse_std::<B>(variance, epsilon, &x);
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
}

#[cfg(feature = "wgpu")]
impl NormBackend for burn::backend::Cube {}

impl<B: Backend + NormBackend, C: CheckpointStrategy> NormBackend for Autodiff<B, C> {
    fn norm_statistics(x: FloatTensor<Self>) -> (FloatTensor<Self>, FloatTensor<Self>) {
        // Statistics take no gradient: nothing flows back through them.
        let (mean, variance) = B::norm_statistics(x.into_primitive());
        (Self::from_inner(mean), Self::from_inner(variance))
    }

    fn norm_relu_train(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        mean: FloatTensor<Self>,
        variance: FloatTensor<Self>,
        epsilon: f64,
    ) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct NormReluTrain;

        impl<B: Backend + NormBackend> Backward<B, 3> for NormReluTrain {
            /// The input and gamma, the batch's mean and variance, epsilon, and the output
            /// (where the ReLU passed gradient).
            type State = (
                NodeId,
                NodeId,
                [B::FloatTensorPrimitive; 2],
                f64,
                B::FloatTensorPrimitive,
            );

            fn backward(
                self,
                ops: Ops<Self::State, 3>,
                grads: &mut Gradients,
                checkpointer: &mut Checkpointer,
            ) {
                let [node_x, node_gamma, node_beta] = ops.parents;
                let grad = grads.consume::<B>(&ops.node);
                let (x_state, gamma_state, [mean, variance], epsilon, output) = ops.state;
                let x = checkpointer.retrieve_node_output::<B::FloatTensorPrimitive>(x_state);
                let gamma =
                    checkpointer.retrieve_node_output::<B::FloatTensorPrimitive>(gamma_state);
                let (x_grad, gamma_grad, beta_grad) =
                    B::norm_relu_train_grads(x, gamma, mean, variance, epsilon, output, grad);
                for (node, grad) in [
                    (node_x, x_grad),
                    (node_gamma, gamma_grad),
                    (node_beta, beta_grad),
                ] {
                    if let Some(node) = node {
                        grads.register::<B>(node.id, grad);
                    }
                }
            }
        }

        match NormReluTrain
            .prepare::<C>([x.node(), gamma.node(), beta.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let x_state = prep.checkpoint(&x);
                let gamma_state = prep.checkpoint(&gamma);
                let [mean, variance] = [mean, variance].map(|t| t.into_primitive());
                let output = B::norm_relu_train(
                    x.into_primitive(),
                    gamma.into_primitive(),
                    beta.into_primitive(),
                    mean.clone(),
                    variance.clone(),
                    epsilon,
                );
                let state = (
                    x_state,
                    gamma_state,
                    [mean, variance],
                    epsilon,
                    output.clone(),
                );
                prep.finish(state, output)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::norm_relu_train(
                x.into_primitive(),
                gamma.into_primitive(),
                beta.into_primitive(),
                mean.into_primitive(),
                variance.into_primitive(),
                epsilon,
            )),
        }
    }
}

/// `norm` on `x`, then a ReLU, as burn's [`BatchNorm::forward`] and `relu` compute them,
/// through [`NormBackend`] when the layer trains (its running statistics updated the same
/// way).
pub fn forward_relu(norm: &BatchNorm, x: Tensor<4>) -> Tensor<4> {
    if !(x.device().is_autodiff() && norm.training.is_enabled()) {
        return relu(norm.forward(x));
    }
    let device = x.device();
    let (mean, variance) =
        <Dispatch as NormBackend>::norm_statistics(x.clone().detach().into_dispatch());
    let [mean, variance]: [Tensor<1>; 2] = [mean, variance].map(Tensor::from_dispatch);
    let output = Tensor::from_dispatch(<Dispatch as NormBackend>::norm_relu_train(
        x.into_dispatch(),
        norm.gamma.val().into_dispatch(),
        norm.beta.val().into_dispatch(),
        mean.clone().into_dispatch(),
        variance.clone().into_dispatch(),
        norm.epsilon,
    ));
    let momentum = norm.momentum;
    let update = |running: Tensor<1>, batch: Tensor<1>| {
        running
            .to_device(&device)
            .mul_scalar(1.0 - momentum)
            .add(batch.detach().mul_scalar(momentum))
            .detach()
    };
    norm.running_mean
        .update(update(norm.running_mean.value_sync(), mean));
    norm.running_var
        .update(update(norm.running_var.value_sync(), variance));
    output
}

#[cfg(test)]
mod tests {
    use burn::backend::ops::{ActivationOps, ModuleOps};

    use super::*;
    use crate::testing::assert_close;

    fn values(tensor: FloatTensor<Flex>) -> Vec<f32> {
        tensor.into_data().try_to_vec::<f32>().unwrap()
    }

    /// The input's, gamma's and beta's gradients, one after another.
    fn grad_values(
        (x, gamma, beta): (FloatTensor<Flex>, FloatTensor<Flex>, FloatTensor<Flex>),
    ) -> Vec<f32> {
        [values(x), values(gamma), values(beta)].concat()
    }

    /// Mean and variance, one after the other.
    fn statistic_values((mean, variance): (FloatTensor<Flex>, FloatTensor<Flex>)) -> Vec<f32> {
        [values(mean), values(variance)].concat()
    }

    #[test]
    fn the_cpu_loops_and_the_composed_operation_equal_burns_batch_norm_and_its_gradients() {
        let (n, c, h) = (3, 4, 5);
        let wave = |len: usize, rate: f32, scale: f32| -> Vec<f32> {
            (0..len)
                .map(|i| (i as f32 * rate).sin() * scale + 0.3)
                .collect()
        };
        let x = || flex_tensor(wave(n * c * h * h, 0.37, 2.0), [n, c, h, h]);
        let gamma = || flex_tensor(wave(c, 0.9, 1.0), [c]);
        let beta = || flex_tensor(wave(c, 1.3, 1.0), [c]);
        let grad = || flex_tensor(wave(n * c * h * h, 0.11, 1.0), [n, c, h, h]);
        let epsilon = 1e-5;
        // burn's generic batch norm in training and its backward, with the ReLU's.
        let burns = Flex::batch_norm_train(x(), gamma(), beta(), epsilon);
        let (mean, variance) = (burns.mean, burns.variance);
        let statistics = || (mean.clone(), variance.clone());
        let output = Flex::relu(burns.output);
        let backward = Flex::batch_norm_train_backward(
            x(),
            gamma(),
            mean.clone(),
            variance.clone(),
            epsilon,
            Flex::relu_backward(output.clone(), grad()),
        );
        let reference = (
            statistic_values(statistics()),
            values(output.clone()),
            grad_values((backward.x_grad, backward.gamma_grad, backward.beta_grad)),
        );
        let loops = (
            statistic_values(Flex::norm_statistics(x())),
            values(Flex::norm_relu_train(
                x(),
                gamma(),
                beta(),
                mean.clone(),
                variance.clone(),
                epsilon,
            )),
            grad_values(Flex::norm_relu_train_grads(
                x(),
                gamma(),
                mean.clone(),
                variance.clone(),
                epsilon,
                output.clone(),
                grad(),
            )),
        );
        let composed = (
            statistic_values(composed::statistics::<Flex>(x())),
            values(composed::train::<Flex>(
                x(),
                gamma(),
                beta(),
                mean.clone(),
                variance.clone(),
                epsilon,
            )),
            grad_values(composed::grads::<Flex>(
                x(),
                gamma(),
                mean.clone(),
                variance.clone(),
                epsilon,
                output.clone(),
                grad(),
            )),
        );
        for (what, ours) in [("the loops", loops), ("composed", composed)] {
            assert_close(&ours.0, &reference.0, 1e-5, &format!("{what}: statistics"));
            assert_close(&ours.1, &reference.1, 1e-5, &format!("{what}: output"));
            assert_close(&ours.2, &reference.2, 1e-4, &format!("{what}: gradients"));
        }
    }
}
