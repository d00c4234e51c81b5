//! Batch norm and the ReLU after it, in training, as an operation of its own: a quarter of a
//! one-grasp training step went to burn's generic `batch_norm_train` and its backward, which
//! move every channel to the front (a transposed copy of the activation) for each of their
//! statistics, and the ReLU then made and read another copy each way. On the CPU backend
//! the statistics, the normalisation with its ReLU and the three gradients are plain loops
//! over each channel's planes; elsewhere (wgpu) burn's own operations. Every batch norm of
//! the nets is followed by a ReLU. The module keeps burn's [`BatchNorm`] (its parameters,
//! running statistics and their update), so checkpoints and the inference path do not
//! change.

use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, TensorMetadata, backend_extension};
use burn::nn::BatchNorm;
use burn::prelude::*;
use burn::tensor::activation::relu;
use burn::tensor::{DType, Slice};

use rayon::prelude::*;

use crate::fresh::planes_from;
use crate::gemm_conv::flex_tensor;

/// The operation on a backend: inputs `[n, c, ...]`, per-channel `gamma` and `beta`, and
/// the batch statistics `[2, c]` (mean, then biased variance) that
/// [`NormBackend::norm_statistics`] computes once per pass.
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "wgpu"))]
pub trait NormBackend: Backend {
    /// The batch mean and biased variance of each channel, `[2, c]`; no gradient.
    fn norm_statistics(x: FloatTensor<Self>) -> FloatTensor<Self> {
        composed::statistics::<Self>(x)
    }

    /// `relu((x - mean) / sqrt(variance + epsilon) * gamma + beta)` with the batch's
    /// `statistics`. Its backward differentiates through the statistics as functions of `x`.
    fn norm_relu_train(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        statistics: FloatTensor<Self>,
        epsilon: f64,
    ) -> FloatTensor<Self> {
        composed::train::<Self>(x, gamma, beta, statistics, epsilon)
    }

    /// The gradients of [`NormBackend::norm_relu_train`], whose `output` it was: input,
    /// gamma and beta. (Each a tensor of its own: a view into one stacked buffer made every
    /// consumer of the input's gradient copy it out first.)
    fn norm_relu_train_grads(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        statistics: FloatTensor<Self>,
        epsilon: f64,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        composed::grads::<Self>(x, gamma, statistics, epsilon, output, grad)
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
    fn norm_statistics(x: FloatTensor<Self>) -> FloatTensor<Self> {
        let Some([c, m]) = layout(&x) else {
            return composed::statistics::<Self>(x);
        };
        let x = x.to_contiguous();
        let values: &[f32] = x.storage();
        let moments: Vec<(f32, f32)> = (0..c)
            .into_par_iter()
            .map(|k| moments(values, c, m, k))
            .collect();
        let mut out: Vec<f32> = moments.iter().map(|m| m.0).collect();
        out.extend(moments.iter().map(|m| m.1));
        flex_tensor(out, vec![2, c])
    }

    fn norm_relu_train(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        statistics: FloatTensor<Self>,
        epsilon: f64,
    ) -> FloatTensor<Self> {
        let Some([c, m]) = layout(&x) else {
            return composed::train::<Self>(x, gamma, beta, statistics, epsilon);
        };
        let shape = x.shape().to_vec();
        let (x, gamma, beta, statistics) = (
            x.to_contiguous(),
            gamma.to_contiguous(),
            beta.to_contiguous(),
            statistics.to_contiguous(),
        );
        let (values, gamma, beta, statistics): (&[f32], &[f32], &[f32], &[f32]) = (
            x.storage(),
            gamma.storage(),
            beta.storage(),
            statistics.storage(),
        );
        let (mean, variance) = statistics.split_at(c);
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
        statistics: FloatTensor<Self>,
        epsilon: f64,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let Some([c, m]) = layout(&x) else {
            return composed::grads::<Self>(x, gamma, statistics, epsilon, output, grad);
        };
        let shape = x.shape().to_vec();
        let (x, gamma, statistics, output, grad) = (
            x.to_contiguous(),
            gamma.to_contiguous(),
            statistics.to_contiguous(),
            output.to_contiguous(),
            grad.to_contiguous(),
        );
        let (values, gamma, statistics): (&[f32], &[f32], &[f32]) =
            (x.storage(), gamma.storage(), statistics.storage());
        // The gradient through the ReLU: none where it cut the value to 0.
        let (y, grad): (&[f32], &[f32]) = (output.storage(), grad.storage());
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
                let (mean, variance) = (statistics[k], statistics[c + k]);
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

/// The operation composed from burn's own (its generic batch norm), for every backend.
mod composed {
    use super::*;

    pub fn statistics<B: Backend>(x: FloatTensor<B>) -> FloatTensor<B> {
        let c = x.shape()[1];
        let device = x.device();
        let gamma = B::float_ones([c].into(), &device, x.dtype().into());
        let beta = B::float_zeros([c].into(), &device, x.dtype().into());
        let result = B::batch_norm_train(x, gamma, beta, 0.0);
        B::float_cat(
            vec![
                B::float_reshape(result.mean, [1, c].into()),
                B::float_reshape(result.variance, [1, c].into()),
            ],
            0,
        )
    }

    /// `[2, c]` statistics as the mean and the variance, `[c]` each.
    pub fn split<B: Backend>(statistics: FloatTensor<B>) -> [FloatTensor<B>; 2] {
        let c = statistics.shape()[1];
        [0, 1].map(|i| {
            B::float_reshape(
                B::float_slice(
                    statistics.clone(),
                    &[Slice::from(i..i + 1), Slice::from(0..c)],
                ),
                [c].into(),
            )
        })
    }

    /// The normalisation with the batch's `statistics` and the ReLU: burn's batch norm and
    /// ReLU.
    pub fn train<B: Backend>(
        x: FloatTensor<B>,
        gamma: FloatTensor<B>,
        beta: FloatTensor<B>,
        statistics: FloatTensor<B>,
        epsilon: f64,
    ) -> FloatTensor<B> {
        let [mean, variance] = split::<B>(statistics);
        B::relu(B::batch_norm(x, gamma, beta, mean, variance, epsilon))
    }

    pub fn grads<B: Backend>(
        x: FloatTensor<B>,
        gamma: FloatTensor<B>,
        statistics: FloatTensor<B>,
        epsilon: f64,
        output: FloatTensor<B>,
        grad: FloatTensor<B>,
    ) -> (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>) {
        let [mean, variance] = split::<B>(statistics);
        let grad = B::relu_backward(output, grad);
        let grads = B::batch_norm_train_backward(x, gamma, mean, variance, epsilon, grad);
        (grads.x_grad, grads.gamma_grad, grads.beta_grad)
    }
}

#[cfg(feature = "wgpu")]
impl NormBackend for burn::backend::Cube {}

impl<B: Backend + NormBackend, C: CheckpointStrategy> NormBackend for Autodiff<B, C> {
    fn norm_statistics(x: FloatTensor<Self>) -> FloatTensor<Self> {
        /// Statistics take no gradient: nothing flows back through them.
        #[derive(Debug)]
        struct Statistics;

        impl<B: Backend> Backward<B, 1> for Statistics {
            type State = ();

            fn backward(self, _: Ops<(), 1>, _: &mut Gradients, _: &mut Checkpointer) {}
        }

        match Statistics
            .prepare::<C>([x.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((), B::norm_statistics(x.into_primitive())),
            OpsKind::UnTracked(prep) => prep.finish(B::norm_statistics(x.into_primitive())),
        }
    }

    fn norm_relu_train(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        statistics: FloatTensor<Self>,
        epsilon: f64,
    ) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct NormReluTrain;

        impl<B: Backend + NormBackend> Backward<B, 3> for NormReluTrain {
            /// The input and gamma, the batch statistics, epsilon, and the output (where the
            /// ReLU passed gradient).
            type State = (
                NodeId,
                NodeId,
                B::FloatTensorPrimitive,
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
                let (x_state, gamma_state, statistics, epsilon, output) = ops.state;
                let x = checkpointer.retrieve_node_output::<B::FloatTensorPrimitive>(x_state);
                let gamma =
                    checkpointer.retrieve_node_output::<B::FloatTensorPrimitive>(gamma_state);
                let (x_grad, gamma_grad, beta_grad) =
                    B::norm_relu_train_grads(x, gamma, statistics, epsilon, output, grad);
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
                let statistics = statistics.into_primitive();
                let output = B::norm_relu_train(
                    x.into_primitive(),
                    gamma.into_primitive(),
                    beta.into_primitive(),
                    statistics.clone(),
                    epsilon,
                );
                let state = (x_state, gamma_state, statistics, epsilon, output.clone());
                prep.finish(state, output)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::norm_relu_train(
                x.into_primitive(),
                gamma.into_primitive(),
                beta.into_primitive(),
                statistics.into_primitive(),
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
    let statistics: Tensor<2> = Tensor::from_dispatch(<Dispatch as NormBackend>::norm_statistics(
        x.clone().detach().into_dispatch(),
    ));
    let output = Tensor::from_dispatch(<Dispatch as NormBackend>::norm_relu_train(
        x.into_dispatch(),
        norm.gamma.val().into_dispatch(),
        norm.beta.val().into_dispatch(),
        statistics.clone().into_dispatch(),
        norm.epsilon,
    ));
    let c = statistics.dims()[1];
    let [mean, variance] = [0, 1].map(|i| statistics.clone().slice([i..i + 1, 0..c]).reshape([c]));
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

    #[test]
    fn the_cpu_loops_equal_the_composed_batch_norm_and_its_gradients() {
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
        let statistics = || Flex::norm_statistics(x());
        let output = || composed::train::<Flex>(x(), gamma(), beta(), statistics(), 1e-5);
        assert_close(
            &values(statistics()),
            &values(composed::statistics::<Flex>(x())),
            1e-5,
            "statistics",
        );
        assert_close(
            &values(Flex::norm_relu_train(
                x(),
                gamma(),
                beta(),
                statistics(),
                1e-5,
            )),
            &values(composed::train::<Flex>(
                x(),
                gamma(),
                beta(),
                statistics(),
                1e-5,
            )),
            1e-5,
            "output",
        );
        assert_close(
            &grad_values(Flex::norm_relu_train_grads(
                x(),
                gamma(),
                statistics(),
                1e-5,
                output(),
                grad(),
            )),
            &grad_values(composed::grads::<Flex>(
                x(),
                gamma(),
                statistics(),
                1e-5,
                output(),
                grad(),
            )),
            1e-4,
            "gradients",
        );
    }
}
