//! The convolution composed from burn's own operations, for every backend: the input padded
//! by one zero at the end of each plane's row-major values, every tap an index into them
//! (a gather), then a matrix product.

use burn::backend::Backend;
use burn::backend::TensorMetadata;
use burn::backend::tensor::FloatTensor;
use burn::tensor::{IndexingUpdateOp, Shape, Slice, TensorData};

use super::Taps;

/// Per tap and output pixel, the index of its input pixel in a plane of `h x h` values
/// followed by one zero (`h x h` stands for the padding).
fn indices(taps: &Taps, h: usize) -> Vec<i64> {
    let side = taps.out_side(h);
    let k = taps.kernel;
    let mut indices = Vec::with_capacity(k * k * side * side);
    for ky in 0..k {
        for kx in 0..k {
            let (lo, hi, first) = taps.inside(kx, h, side);
            for oy in 0..side {
                let row = taps.source_row(ky, oy, h);
                indices.extend((0..side).map(|ox| match row {
                    Some(iy) if (lo..hi).contains(&ox) => {
                        (iy * h + first + (ox - lo) * taps.stride) as i64
                    }
                    _ => (h * h) as i64,
                }));
            }
        }
    }
    indices
}

fn index_tensor<B: Backend>(taps: &Taps, h: usize, device: &B::Device) -> B::IntTensorPrimitive {
    let indices = indices(taps, h);
    let n = indices.len();
    B::int_from_data(TensorData::new(indices, [n]), device)
}

/// `x` `[n, c, h, h]` unfolded to `[n, c x k x k, side^2]`, rows in the weights'
/// `(channel, kernel row, kernel column)` order.
pub(super) fn unfold<B: Backend>(x: FloatTensor<B>, taps: Taps) -> FloatTensor<B> {
    let [n, c, h, _] = x.shape().dims();
    let device = x.device();
    let side = taps.out_side(h);
    let flat = B::float_reshape(x, Shape::new([n * c, h * h]));
    let zero = B::float_zeros(Shape::new([n * c, 1]), &device, flat.dtype().into());
    let padded = B::float_cat(vec![flat, zero], 1);
    let columns = B::float_select(padded, 1, index_tensor::<B>(&taps, h, &device));
    B::float_reshape(
        columns,
        Shape::new([n, c * taps.per_channel(), side * side]),
    )
}

/// The reverse of [`unfold`]: columns `[n, c x k x k, side^2]` added back to `[n, c, h, h]`.
pub(super) fn fold<B: Backend>(
    columns: FloatTensor<B>,
    taps: Taps,
    channels: usize,
    h: usize,
) -> FloatTensor<B> {
    let [n, _, _] = columns.shape().dims();
    let device = columns.device();
    let side = taps.out_side(h);
    let dtype = columns.dtype();
    let columns = B::float_reshape(
        columns,
        Shape::new([n * channels, taps.per_channel() * side * side]),
    );
    let zeros = B::float_zeros(Shape::new([n * channels, h * h + 1]), &device, dtype.into());
    let planes = B::float_select_assign(
        zeros,
        1,
        index_tensor::<B>(&taps, h, &device),
        columns,
        IndexingUpdateOp::Add,
    );
    let planes = B::float_slice(
        planes,
        &[Slice::from(0..n * channels), Slice::from(0..h * h)],
    );
    B::float_reshape(planes, Shape::new([n, channels, h, h]))
}

/// The weights as `[1, o, c x k x k]`.
fn weight_rows<B: Backend>(weight: FloatTensor<B>) -> FloatTensor<B> {
    let [o, c, k, _] = weight.shape().dims();
    B::float_reshape(weight, Shape::new([1, o, c * k * k]))
}

pub(super) fn conv<B: Backend>(
    x: FloatTensor<B>,
    weight: FloatTensor<B>,
    taps: Taps,
) -> FloatTensor<B> {
    let [n, _, h, _] = x.shape().dims();
    let o = weight.shape().dims::<4>()[0];
    let side = taps.out_side(h);
    let y = B::float_matmul(weight_rows::<B>(weight), unfold::<B>(x, taps));
    B::float_reshape(y, Shape::new([n, o, side, side]))
}

pub(super) fn x_grad<B: Backend>(
    grad: FloatTensor<B>,
    weight: FloatTensor<B>,
    taps: Taps,
    h: usize,
) -> FloatTensor<B> {
    let [n, o, side, _] = grad.shape().dims();
    let c = weight.shape().dims::<4>()[1];
    let grad = B::float_reshape(grad, Shape::new([n, o, side * side]));
    let columns = B::float_matmul(B::float_transpose(weight_rows::<B>(weight)), grad);
    fold::<B>(columns, taps, c, h)
}

pub(super) fn weight_grad<B: Backend>(
    x: FloatTensor<B>,
    grad: FloatTensor<B>,
    taps: Taps,
) -> FloatTensor<B> {
    let [n, c, _, _] = x.shape().dims();
    let [_, o, side, _] = grad.shape().dims();
    let k = taps.kernel;
    let grad = B::float_reshape(grad, Shape::new([n, o, side * side]));
    let per_item = B::float_matmul(grad, B::float_transpose(unfold::<B>(x, taps)));
    let summed = B::float_sum_dim(per_item, 0);
    B::float_reshape(summed, Shape::new([o, c, k, k]))
}
