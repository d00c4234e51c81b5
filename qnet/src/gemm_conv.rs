//! A square convolution as one matrix product of its weights with its input unfolded into
//! columns (im2col), and that convolution as one differentiable operation of its own.
//!
//! The inference form ([`crate::inference`]) unfolds a band of output rows at a time into a
//! buffer that stays in the cache and multiplies it there. Training does the same through
//! [`ConvBackend`], a burn backend extension with its own backward: the input's gradient is
//! the weights' transpose times the output's gradient, folded back onto the input band by
//! band (col2im), and the weights' gradient the output's gradient times the columns,
//! unfolded again band by band rather than kept. Composed from burn's own operations (an
//! unfolding gather, a matrix product, their autodiff), the columns of a training step were a
//! hundred megabytes written, transposed, packed and scattered back, element by element
//! where burn-flex has no parallel path. The composed version stays as the reference the CPU
//! loops are tested against. Only the CPU backend takes this route: on a GPU the nets
//! convolve with burn's own `conv2d`, whose kernels and gradients are tuned for it.

use burn::backend::TensorMetadata;
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, binary};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, backend_extension};
use burn::prelude::*;

mod columns;
mod composed;
mod flex;
mod multiply;

pub use columns::Taps;
pub(crate) use columns::unfold_item;
pub(crate) use multiply::{View, bands, flex_tensor, multiply};

/// The convolution as a backend operation: forward, and the two gradients its backward needs.
/// Inputs are `[n, c, h, h]`, weights `[o, c, k, k]`, outputs `[n, o, side, side]`; no bias.
#[backend_extension(Flex, Autodiff)]
pub trait ConvBackend: Backend {
    fn conv_taps(x: FloatTensor<Self>, weight: FloatTensor<Self>, taps: Taps) -> FloatTensor<Self> {
        composed::conv::<Self>(x, weight, taps)
    }

    /// The input's gradient from the output's, for an input of side `h`.
    fn conv_taps_x_grad(
        grad: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        taps: Taps,
        h: usize,
    ) -> FloatTensor<Self> {
        composed::x_grad::<Self>(grad, weight, taps, h)
    }

    /// The weights' gradient from the output's.
    fn conv_taps_weight_grad(
        x: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        taps: Taps,
    ) -> FloatTensor<Self> {
        composed::weight_grad::<Self>(x, grad, taps)
    }
}

impl<B: Backend + ConvBackend, C: CheckpointStrategy> ConvBackend for Autodiff<B, C> {
    fn conv_taps(x: FloatTensor<Self>, weight: FloatTensor<Self>, taps: Taps) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct ConvTaps;

        impl<B: Backend + ConvBackend> Backward<B, 2> for ConvTaps {
            /// The input (for the weights' gradient) and the weights (for the input's), each
            /// kept only when the other takes a gradient; the taps; the input's side.
            type State = (Option<NodeId>, Option<NodeId>, Taps, usize);

            fn backward(
                self,
                ops: Ops<Self::State, 2>,
                grads: &mut Gradients,
                checkpointer: &mut Checkpointer,
            ) {
                let (x, weight, taps, h) = ops.state;
                let x = x.map(|x| checkpointer.retrieve_node_output(x));
                let weight = weight.map(|weight| checkpointer.retrieve_node_output(weight));
                binary::<B, _, _>(
                    ops.parents,
                    ops.node,
                    grads,
                    |grad| B::conv_taps_x_grad(grad, weight.expect("the weights"), taps, h),
                    |grad| B::conv_taps_weight_grad(x.expect("the input"), grad, taps),
                );
            }
        }

        let h = x.primitive().shape().dims::<4>()[2];
        let (x_tracked, weight_tracked) = (x.is_tracked(), weight.is_tracked());
        match ConvTaps
            .prepare::<C>([x.node(), weight.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let x_state = weight_tracked.then(|| prep.checkpoint(&x));
                let weight_state = x_tracked.then(|| prep.checkpoint(&weight));
                let y = B::conv_taps(x.into_primitive(), weight.into_primitive(), taps);
                prep.finish((x_state, weight_state, taps, h), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::conv_taps(
                x.into_primitive(),
                weight.into_primitive(),
                taps,
            )),
        }
    }
}

/// `x` (`[n, c, h, h]`) convolved with `weight` (`[o, c, k, k]`) at `taps`, without bias, on
/// the CPU backend (differentiable on its autodiff device).
pub fn conv(x: Tensor<4>, weight: Tensor<4>, taps: Taps) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as ConvBackend>::conv_taps(
        x.into_dispatch(),
        weight.into_dispatch(),
        taps,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::assert_close;
    use burn::backend::Flex;

    fn values(tensor: FloatTensor<Flex>) -> Vec<f32> {
        tensor.into_data().try_to_vec::<f32>().unwrap()
    }

    fn wave(len: usize, rate: f32) -> Vec<f32> {
        (0..len).map(|i| (i as f32 * rate).sin()).collect()
    }

    #[test]
    fn the_cpu_loops_equal_the_composed_convolution_and_its_gradients_every_way_the_nets_convolve()
    {
        // An odd side, so a stride-2 row ends on a tap that lacks its pair.
        let (n, c, o, h) = (2, 3, 4, 9);
        // 3x3 (stride 2; stride 1, dilations 1 and 2) and the head's pointwise 1x1.
        for (kernel, stride, dilation) in [(3, 2, 1), (3, 1, 1), (3, 1, 2), (1, 1, 1)] {
            let taps = Taps {
                kernel,
                stride,
                dilation,
                padding: dilation * (kernel - 1) / 2,
            };
            let (k, side) = (kernel, taps.out_side(h));
            let x = || flex_tensor(wave(n * c * h * h, 0.37), [n, c, h, h]);
            let weight = || flex_tensor(wave(o * c * k * k, 0.53), [o, c, k, k]);
            let grad = || flex_tensor(wave(n * o * side * side, 0.11), [n, o, side, side]);
            let what = |part: &str| format!("{part}, {taps:?}");
            assert_close(
                &values(Flex::conv_taps(x(), weight(), taps)),
                &values(composed::conv::<Flex>(x(), weight(), taps)),
                1e-5,
                &what("output"),
            );
            assert_close(
                &values(Flex::conv_taps_x_grad(grad(), weight(), taps, h)),
                &values(composed::x_grad::<Flex>(grad(), weight(), taps, h)),
                1e-5,
                &what("input gradient"),
            );
            assert_close(
                &values(Flex::conv_taps_weight_grad(x(), grad(), taps)),
                &values(composed::weight_grad::<Flex>(x(), grad(), taps)),
                1e-5,
                &what("weight gradient"),
            );
        }
    }
}
