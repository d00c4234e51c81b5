//! The values at chosen pixels of low-resolution maps, as one operation: the sum over each
//! item's plane of its maps weighted by that item's weights (`qnets::QNets::at_pixels`
//! folds the rotation back and the upsampling to a pixel into at most 16 weights an item).
//! Composed from burn's operations, the product, the two sums and their backward (fills,
//! products, sums) were about ten small kernels of a GPU training step; on a GPU (wgpu) the sums
//! are one kernel and the gradient another, written laid out as the maps lie (a
//! convolution's output, channels last), as the head convolution's backward reads them. On
//! the CPU the operation is burn's, as before, so the trained figures do not move.

#[cfg(feature = "wgpu")]
mod cube;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::prelude::*;

/// The operation on a backend: `maps` `[n, heads, s, s]` and `weights` `[n, 1, s, s]`.
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"))]
pub trait PlaneSumBackend: Backend {
    /// `[n, heads]`: each item's and head's plane of `maps` times the item's `weights`,
    /// summed.
    #[fusion(meta = |maps, _weights| {
        burn::backend::fusion::custom::TensorSpec::new([maps.shape[0], maps.shape[1]].into(), maps.dtype)
    })]
    fn weighted_plane_sums(
        maps: FloatTensor<Self>,
        weights: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        composed::sums::<Self>(maps, weights)
    }

    /// The gradient of [`PlaneSumBackend::weighted_plane_sums`] for `maps` (shaped as
    /// `maps`), from the sums' gradient `grad` `[n, heads]`: `grad` times the weights.
    #[fusion(meta = |maps, _weights, _grad| maps.clone())]
    fn weighted_plane_sums_grad(
        maps: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        composed::grad::<Self>(maps, weights, grad)
    }
}

impl PlaneSumBackend for Flex {}

impl<B: Backend + PlaneSumBackend, C: CheckpointStrategy> PlaneSumBackend for Autodiff<B, C> {
    fn weighted_plane_sums(
        maps: FloatTensor<Self>,
        weights: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct WeightedPlaneSums;

        impl<B: Backend + PlaneSumBackend> Backward<B, 1> for WeightedPlaneSums {
            /// The maps (for their shape and layout) and the weights.
            type State = (B::FloatTensorPrimitive, B::FloatTensorPrimitive);

            fn backward(
                self,
                ops: Ops<Self::State, 1>,
                grads: &mut Gradients,
                _checkpointer: &mut Checkpointer,
            ) {
                let [node_maps] = ops.parents;
                let grad = grads.consume::<B>(&ops.node);
                let (maps, weights) = ops.state;
                if let Some(node) = node_maps {
                    grads.register::<B>(node.id, B::weighted_plane_sums_grad(maps, weights, grad));
                }
            }
        }

        // The weights are data: no gradient flows to them.
        let weights = weights.into_primitive();
        match WeightedPlaneSums
            .prepare::<C>([maps.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let maps = maps.into_primitive();
                let sums = B::weighted_plane_sums(maps.clone(), weights.clone());
                prep.finish((maps, weights), sums)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::weighted_plane_sums(maps.into_primitive(), weights))
            }
        }
    }
}

/// The operation composed from burn's own: on the CPU (the operations `at_pixels` always
/// ran, so the trained figures do not move), and on a GPU where the kernels do not take the
/// tensors.
mod composed {
    use burn::backend::tensor::FloatTensor;
    use burn::backend::{Backend, TensorMetadata};

    /// A product, then a sum over the columns and one over the rows.
    pub(super) fn sums<B: Backend>(
        maps: FloatTensor<B>,
        weights: FloatTensor<B>,
    ) -> FloatTensor<B> {
        let [n, heads] = [maps.shape()[0], maps.shape()[1]];
        let products = B::float_mul(maps, weights);
        let sums = B::float_sum_dim(B::float_sum_dim(products, 3), 2);
        B::float_reshape(sums, [n, heads].into())
    }

    /// The sums' gradient, per (item, head), times the item's weights.
    pub(super) fn grad<B: Backend>(
        maps: FloatTensor<B>,
        weights: FloatTensor<B>,
        grad: FloatTensor<B>,
    ) -> FloatTensor<B> {
        let [n, heads] = [maps.shape()[0], maps.shape()[1]];
        B::float_mul(B::float_reshape(grad, [n, heads, 1, 1].into()), weights)
    }
}

/// `[n, heads]`: the sum over each item's plane of `maps` `[n, heads, s, s]` times the
/// item's `weights` `[n, 1, s, s]`, through [`PlaneSumBackend`].
pub fn weighted_plane_sums(maps: Tensor<4>, weights: Tensor<4>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as PlaneSumBackend>::weighted_plane_sums(
        maps.into_dispatch(),
        weights.into_dispatch(),
    ))
}
