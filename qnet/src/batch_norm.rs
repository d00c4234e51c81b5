//! Batch norm and the ReLU after it, in training, as an operation of its own: a quarter of a
//! one-grasp training step went to burn's generic `batch_norm_train` and its backward, which
//! move every channel to the front (a transposed copy of the activation) for each of their
//! statistics, and the ReLU then made and read another copy each way. On the CPU backend
//! the statistics, the normalisation with its ReLU and the three gradients are plain loops
//! over each channel's planes; on a GPU (wgpu) the statistics and the gradients are a
//! kernel each (threads summing each channel in shared memory; the statistics' kernel moves
//! the running statistics too), and the normalisation with its ReLU burn's element-wise
//! operations, which burn's fusion joins with what is around them. Every batch norm of the
//! nets is followed by a ReLU. The module keeps burn's [`BatchNorm`] (its parameters and
//! running statistics, moved as burn moves them), so checkpoints and the inference path do
//! not change.

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
use burn::module::{Module, ModuleMapper, Param, RunningState};
use burn::nn::BatchNorm;
use burn::prelude::*;
use burn::tensor::activation::relu;

/// The operation on a backend: inputs `[n, c, ...]`, per-channel `gamma` and `beta`, and
/// the batch's mean and biased variance per channel (`[c]` each), which
/// [`NormBackend::norm_statistics`] computes once per pass. (Each a tensor of its own: a
/// view into one stacked buffer cost a device a copy and a slice per use.)
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"))]
pub trait NormBackend: Backend {
    /// The batch mean and biased variance of each channel, and the running mean and
    /// variance moved toward them as burn's [`BatchNorm`] moves them (`running (1 -
    /// momentum) + batch momentum`), `[c]` each; no gradient. (The update is part of the
    /// statistics' operation: on a GPU, as operations of its own, it was a kernel a norm,
    /// and issued after the normalisation it split the normalisation's per-channel
    /// arithmetic into small kernels of its own; results/gpu.md.)
    #[fusion(meta = |x, _running_mean, _running_variance, _momentum| {
        let channels = burn::backend::fusion::custom::TensorSpec::new([x.shape[1]].into(), x.dtype);
        (channels.clone(), channels.clone(), channels.clone(), channels)
    })]
    fn norm_statistics(
        x: FloatTensor<Self>,
        running_mean: FloatTensor<Self>,
        running_variance: FloatTensor<Self>,
        momentum: f64,
    ) -> (
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
    ) {
        composed::with_running::<Self>(
            composed::statistics::<Self>(x),
            [running_mean, running_variance],
            momentum,
        )
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

/// [`NormBackend::norm_statistics`]'s: the batch's mean and variance, then the running mean
/// and variance after the update.
pub type Statistics<B> = (
    FloatTensor<B>,
    FloatTensor<B>,
    FloatTensor<B>,
    FloatTensor<B>,
);

impl<B: Backend + NormBackend, C: CheckpointStrategy> NormBackend for Autodiff<B, C> {
    fn norm_statistics(
        x: FloatTensor<Self>,
        running_mean: FloatTensor<Self>,
        running_variance: FloatTensor<Self>,
        momentum: f64,
    ) -> Statistics<Self> {
        // Statistics take no gradient: nothing flows back through them.
        let (mean, variance, running_mean, running_variance) = B::norm_statistics(
            x.into_primitive(),
            running_mean.into_primitive(),
            running_variance.into_primitive(),
            momentum,
        );
        (
            Self::from_inner(mean),
            Self::from_inner(variance),
            Self::from_inner(running_mean),
            Self::from_inner(running_variance),
        )
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
    let running = |state: &RunningState<Tensor<1>>| {
        state
            .value_sync()
            .to_device(&device)
            .detach()
            .into_dispatch()
    };
    let (mean, variance, running_mean, running_variance) =
        <Dispatch as NormBackend>::norm_statistics(
            x.clone().detach().into_dispatch(),
            running(&norm.running_mean),
            running(&norm.running_var),
            norm.momentum,
        );
    set(&norm.running_mean, running_mean);
    set(&norm.running_var, running_variance);
    Tensor::from_dispatch(<Dispatch as NormBackend>::norm_relu_train(
        x.into_dispatch(),
        norm.gamma.val().into_dispatch(),
        norm.beta.val().into_dispatch(),
        mean,
        variance,
        norm.epsilon,
    ))
}

/// Sets `state`'s value. burn's [`RunningState::update`] keeps a value aside per thread
/// until a `value_sync` averages the threads' values (a division even for one: on a GPU a
/// kernel a state each step); a net trains on one thread. A clone of a running state shares
/// its value, and mapping one sets the value (burn's `Module::map` for `RunningState`).
fn set(state: &RunningState<Tensor<1>>, value: FloatTensor<Dispatch>) {
    /// A mapper that puts its value in place of the one float tensor it meets.
    struct Put(Option<FloatTensor<Dispatch>>);

    impl ModuleMapper for Put {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let (id, _, mapper) = param.consume();
            let value = self.0.take().expect("a running state holds one tensor");
            Param::from_mapped_value(id, Tensor::from_dispatch(value), mapper)
        }
    }

    let _ = state.clone().map(&mut Put(Some(value)));
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

    /// The batch's mean and variance and the running ones, one after another.
    fn statistic_values(
        (mean, variance, running_mean, running_variance): Statistics<Flex>,
    ) -> Vec<f32> {
        [mean, variance, running_mean, running_variance]
            .map(values)
            .concat()
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
        let running = || [wave(c, 0.7, 0.2), wave(c, 0.5, 0.1)].map(|r| flex_tensor(r, [c]));
        let (epsilon, momentum) = (1e-5, 0.1);
        // burn's generic batch norm in training and its backward, with the ReLU's.
        let burns = Flex::batch_norm_train(x(), gamma(), beta(), epsilon);
        let (mean, variance) = (burns.mean, burns.variance);
        // burn's `BatchNorm` moves its running statistics by `running (1 - m) + batch m`.
        let moved = |running: FloatTensor<Flex>, batch: &FloatTensor<Flex>| {
            let batch = values(batch.clone());
            let moved = (values(running).iter().zip(&batch))
                .map(|(&r, &b)| r * (1.0 - momentum) + b * momentum)
                .collect();
            flex_tensor(moved, [c])
        };
        let statistics = || {
            let [running_mean, running_variance] = running();
            let running_mean = moved(running_mean, &mean);
            let running_variance = moved(running_variance, &variance);
            (
                mean.clone(),
                variance.clone(),
                running_mean,
                running_variance,
            )
        };
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
            statistic_values({
                let [running_mean, running_variance] = running();
                Flex::norm_statistics(x(), running_mean, running_variance, momentum as f64)
            }),
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
            statistic_values(composed::with_running::<Flex>(
                composed::statistics::<Flex>(x()),
                running(),
                momentum as f64,
            )),
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
