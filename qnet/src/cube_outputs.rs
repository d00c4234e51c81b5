//! Output tensors for this workspace's own CubeCL kernels (the batch norm's, the plane
//! sums', the learner's Adam): allocated unwritten, laid out as an input is, so a kernel's
//! threads walk its inputs and outputs in one order and the convolutions after it find their
//! operands laid out as they read them. And which inputs the kernels take.

use burn::backend::ops::FloatTensorOps;
use burn::backend::wgpu::{CubeBackend, CubeTensor};
use burn::tensor::{DType, FloatDType, Shape};

/// Whether the kernels take these tensors: they read and write f32 values (elsewhere each
/// falls back to burn's operations composed).
pub fn all_f32<'a>(tensors: impl IntoIterator<Item = &'a CubeTensor>) -> bool {
    tensors.into_iter().all(|t| t.dtype == DType::F32)
}

/// A contiguous f32 tensor of `shape` on `like`'s device, its values not yet written.
pub fn empty(like: &CubeTensor, shape: Shape) -> CubeTensor {
    CubeBackend::float_empty(shape, &like.device, FloatDType::F32)
}

/// An f32 tensor of `like`'s shape, its values not yet written, laid out in memory as
/// `like` is when that is dense (a convolution's output has its channels last, and a
/// gradient laid out otherwise would be copied back before the convolution's backward
/// pass), else contiguous.
pub fn empty_like(like: &CubeTensor) -> CubeTensor {
    let (shape, strides) = (like.meta.shape(), like.meta.strides());
    let rank = shape.num_dims();
    // The dimensions from the outermost in memory.
    let mut order: Vec<usize> = (0..rank).collect();
    if like.is_contiguous_buffer() && like.is_nonoverlapping() {
        // Of dimensions with one stride, those of one value inside the other: so the strides
        // come out as `like`'s, which is what a convolution checks before it reads a tensor
        // as it lies.
        order.sort_by_key(|&d| std::cmp::Reverse((strides[d], shape[d])));
    }
    let stored = empty(like, order.iter().map(|&d| shape[d]).collect());
    let mut axes = vec![0; rank];
    for (at, &d) in order.iter().enumerate() {
        axes[d] = at;
    }
    CubeBackend::float_permute(stored, &axes)
}
