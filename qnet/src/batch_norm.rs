//! Batch norm and the ReLU after it, in training, as an operation of its own: a quarter of a
//! one-grasp training step went to burn's generic `batch_norm_train` and its backward, which
//! move every channel to the front (a transposed copy of the activation) for each of their
//! statistics, and the ReLU then made and read another copy each way. On the CPU backend
//! the statistics, the normalisation with its ReLU and the three gradients are plain loops
//! over each channel's planes; on a GPU (wgpu) the statistics and the gradients are a
//! kernel each (threads summing each channel in shared memory), and the normalisation with
//! its ReLU burn's element-wise operations, which burn's fusion joins with what is around
//! them. Every batch norm of the nets is followed by a ReLU. The module keeps burn's
//! [`BatchNorm`] (its parameters, running statistics and their update), so checkpoints and
//! the inference path do not change.

mod composed;
#[cfg(feature = "wgpu")]
mod cube;
mod flex;

use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, backend_extension};
use burn::nn::BatchNorm;
use burn::prelude::*;
use burn::tensor::activation::relu;

/// The operation on a backend: inputs `[n, c, ...]`, per-channel `gamma` and `beta`, and
/// the batch's mean and biased variance per channel (`[c]` each), which
/// [`NormBackend::norm_statistics`] computes once per pass. (Each a tensor of its own: a
/// view into one stacked buffer cost a device a copy and a slice per use.)
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"))]
pub trait NormBackend: Backend {
    /// The batch mean and biased variance of each channel, `[c]` each; no gradient.
    #[fusion(meta = |x| {
        let channels = burn::backend::fusion::custom::TensorSpec::new([x.shape[1]].into(), x.dtype);
        (channels.clone(), channels)
    })]
    fn norm_statistics(x: FloatTensor<Self>) -> (FloatTensor<Self>, FloatTensor<Self>) {
        composed::statistics::<Self>(x)
    }

    /// `relu((x - mean) / sqrt(variance + epsilon) * gamma + beta)` with the batch's
    /// statistics. Its backward differentiates through the statistics as functions of `x`.
    #[fusion(default)]
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
    #[fusion(meta = |x, gamma, _mean, _variance, _epsilon, _output, _grad| {
        (x.clone(), gamma.clone(), gamma.clone())
    })]
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
    // The running statistics are updated before the normalisation is issued, not after: on
    // a GPU burn's fusion then joins the normalisation's per-channel arithmetic with the
    // normalisation itself, where the update's operations, issued between it and the next
    // layer's, split it into small kernels of its own (results/gpu.md).
    let momentum = norm.momentum;
    let update = |running: Tensor<1>, batch: Tensor<1>| {
        running
            .to_device(&device)
            .mul_scalar(1.0 - momentum)
            .add(batch.detach().mul_scalar(momentum))
            .detach()
    };
    norm.running_mean
        .update(update(norm.running_mean.value_sync(), mean.clone()));
    norm.running_var
        .update(update(norm.running_var.value_sync(), variance.clone()));
    Tensor::from_dispatch(<Dispatch as NormBackend>::norm_relu_train(
        x.into_dispatch(),
        norm.gamma.val().into_dispatch(),
        norm.beta.val().into_dispatch(),
        mean.into_dispatch(),
        variance.into_dispatch(),
        norm.epsilon,
    ))
}

#[cfg(test)]
mod tests {
    use burn::backend::Flex;
    use burn::backend::ops::{ActivationOps, ModuleOps};

    use super::*;
    use crate::gemm_conv::flex_tensor;
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
