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

use std::ops::Range;

use burn::backend::TensorMetadata;
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, binary};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::prelude::*;
use burn::tensor::{DType, IndexingUpdateOp, Shape, Slice, TensorData};
use rayon::prelude::*;

use crate::fresh::{planes_from, zeroed};

/// Where a square kernel's taps fall: its size, stride, dilation and zero padding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Taps {
    pub kernel: usize,
    pub stride: usize,
    pub dilation: usize,
    pub padding: usize,
}

impl Taps {
    /// Side of the output for an input of side `h`.
    pub fn out_side(&self, h: usize) -> usize {
        (h + 2 * self.padding - self.dilation * (self.kernel - 1) - 1) / self.stride + 1
    }

    /// Rows of the columns per input channel.
    pub fn per_channel(&self) -> usize {
        self.kernel * self.kernel
    }

    /// A 1x1 kernel at stride 1 without padding: its unfolded columns are the input itself.
    fn pointwise(&self) -> bool {
        self.kernel == 1 && self.stride == 1 && self.padding == 0
    }

    /// For the tap `kx` columns to the right, the output columns whose input column lies
    /// inside an image of side `h`, `[lo, hi)`, and the input column of the first of them.
    fn inside(&self, kx: usize, h: usize, side: usize) -> (usize, usize, usize) {
        let (s, pad) = (self.stride, self.padding);
        let shift = (kx * self.dilation) as isize - pad as isize;
        let lo = ((-shift).max(0) as usize).div_ceil(s).min(side);
        let last = h as isize - 1 - shift;
        let hi = if last < 0 {
            0
        } else {
            (last as usize / s + 1).min(side)
        };
        (lo, hi, ((lo * s) as isize + shift).max(0) as usize)
    }

    /// The input row under tap row `ky` of output row `oy`, if inside an image of side `h`.
    fn source_row(&self, ky: usize, oy: usize, h: usize) -> Option<usize> {
        let iy = (oy * self.stride + ky * self.dilation) as isize - self.padding as isize;
        (0..h as isize).contains(&iy).then_some(iy as usize)
    }
}

/// Unfolds one channel `plane` (`h x h`) for the output rows `rows`: `out` gets a row per tap
/// `(ky, kx)`, each holding, for every pixel of those output rows, the input pixel under the
/// tap (zero in the padding).
fn unfold_channel(plane: &[f32], h: usize, taps: &Taps, rows: Range<usize>, out: &mut [f32]) {
    let side = taps.out_side(h);
    let n = rows.len() * side;
    let k = taps.kernel;
    for ky in 0..k {
        for kx in 0..k {
            let row = &mut out[(ky * k + kx) * n..][..n];
            let (lo, hi, first) = taps.inside(kx, h, side);
            for (oy, out_row) in rows.clone().zip(row.chunks_exact_mut(side)) {
                match taps.source_row(ky, oy, h) {
                    Some(iy) if lo < hi => {
                        let source = &plane[iy * h + first..(iy + 1) * h];
                        out_row[..lo].fill(0.0);
                        gather(&mut out_row[lo..hi], source, taps.stride);
                        out_row[hi..].fill(0.0);
                    }
                    _ => out_row.fill(0.0),
                }
            }
        }
    }
}

/// The reverse of [`unfold_channel`]: adds each tap row of `columns` (the output rows `rows`)
/// back onto the input pixel it was taken from, into `plane` (`h x h`).
fn fold_channel(columns: &[f32], h: usize, taps: &Taps, rows: Range<usize>, plane: &mut [f32]) {
    let side = taps.out_side(h);
    let n = rows.len() * side;
    let k = taps.kernel;
    for ky in 0..k {
        for kx in 0..k {
            let row = &columns[(ky * k + kx) * n..][..n];
            let (lo, hi, first) = taps.inside(kx, h, side);
            if lo >= hi {
                continue;
            }
            for (oy, grad_row) in rows.clone().zip(row.chunks_exact(side)) {
                if let Some(iy) = taps.source_row(ky, oy, h) {
                    let target = &mut plane[iy * h + first..(iy + 1) * h];
                    scatter_add(target, &grad_row[lo..hi], taps.stride);
                }
            }
        }
    }
}

/// `out[j] = source[j * stride]`; the strides the nets use get loops the compiler can
/// vectorise.
fn gather(out: &mut [f32], source: &[f32], stride: usize) {
    match stride {
        1 => out.copy_from_slice(&source[..out.len()]),
        2 => gather_fixed::<2>(out, source),
        _ => out
            .iter_mut()
            .zip(source.iter().step_by(stride))
            .for_each(|(o, &v)| *o = v),
    }
}

/// `target[j * stride] += values[j]`: the reverse of [`gather`].
fn scatter_add(target: &mut [f32], values: &[f32], stride: usize) {
    match stride {
        1 => target.iter_mut().zip(values).for_each(|(t, &v)| *t += v),
        2 => scatter_add_fixed::<2>(target, values),
        _ => target
            .iter_mut()
            .step_by(stride)
            .zip(values)
            .for_each(|(t, &v)| *t += v),
    }
}

fn scatter_add_fixed<const S: usize>(target: &mut [f32], values: &[f32]) {
    let whole = values.len().min(target.len() / S);
    for (taps, &v) in target.chunks_exact_mut(S).zip(&values[..whole]) {
        taps[0] += v;
    }
    if whole < values.len() {
        target[whole * S] += values[whole];
    }
}

fn gather_fixed<const S: usize>(out: &mut [f32], source: &[f32]) {
    // The last tap may lack the row's final `S - 1` values; take it apart.
    let whole = out.len().min(source.len() / S);
    for (o, taps) in out[..whole].iter_mut().zip(source.chunks_exact(S)) {
        *o = taps[0];
    }
    if whole < out.len() {
        out[whole] = source[whole * S];
    }
}

/// A matrix in memory: its first value and the distance between rows and between columns.
#[derive(Clone, Copy)]
pub(crate) struct View {
    pub ptr: *const f32,
    pub row: isize,
    pub col: isize,
}

impl View {
    /// Rows of contiguous values, `row` apart.
    pub fn rows(ptr: *const f32, row: usize) -> Self {
        Self {
            ptr,
            row: row as isize,
            col: 1,
        }
    }

    /// The transpose of [`View::rows`]: columns of contiguous values, `col` apart.
    pub fn columns(ptr: *const f32, col: usize) -> Self {
        Self {
            ptr,
            row: 1,
            col: col as isize,
        }
    }
}

/// `dst = lhs x rhs` (`m x k` times `k x n`), or `dst += lhs x rhs` when `accumulate`, on this
/// thread (the callers spread their work over the cores themselves).
///
/// # Safety
/// Every view must cover its matrix inside one live allocation, and `dst` must be writable
/// and not overlap the others.
pub(crate) unsafe fn multiply(
    [m, n, k]: [usize; 3],
    dst: (*mut f32, isize, isize),
    accumulate: bool,
    lhs: View,
    rhs: View,
) {
    // SAFETY: passed on from the caller.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.0,
            dst.2,
            dst.1,
            accumulate,
            lhs.ptr,
            lhs.col,
            lhs.row,
            rhs.ptr,
            rhs.col,
            rhs.row,
            if accumulate { 1.0 } else { 0.0 },
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

/// How many unfolded values a band of output rows may take (96 KiB): small enough to stay in
/// a core's cache beside the weights and the output.
const BAND_VALUES: usize = 24 * 1024;

/// The output rows, a band at a time, when `depth` unfolded rows of `side` pixels each are in
/// play.
pub(crate) fn bands(depth: usize, side: usize) -> impl Iterator<Item = Range<usize>> {
    let rows = (BAND_VALUES / (depth * side)).clamp(1, side);
    (0..side)
        .step_by(rows)
        .map(move |first| first..(first + rows).min(side))
}

/// A CPU tensor of `values`.
pub(crate) fn flex_tensor(values: Vec<f32>, shape: impl Into<Shape>) -> FloatTensor<Flex> {
    <Flex as FloatTensorOps<Flex>>::float_from_data(
        TensorData::new(values, shape),
        &Default::default(),
    )
}

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

/// The convolution composed from burn's own operations, for every backend: the input padded
/// by one zero at the end of each plane's row-major values, every tap an index into them
/// (a gather), then a matrix product.
mod composed {
    use super::*;

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

    fn index_tensor<B: Backend>(
        taps: &Taps,
        h: usize,
        device: &B::Device,
    ) -> B::IntTensorPrimitive {
        let indices = indices(taps, h);
        let n = indices.len();
        B::int_from_data(TensorData::new(indices, [n]), device)
    }

    /// `x` `[n, c, h, h]` unfolded to `[n, c x k x k, side^2]`, rows in the weights'
    /// `(channel, kernel row, kernel column)` order.
    pub fn unfold<B: Backend>(x: FloatTensor<B>, taps: Taps) -> FloatTensor<B> {
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
    pub fn fold<B: Backend>(
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

    pub fn conv<B: Backend>(
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

    pub fn x_grad<B: Backend>(
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

    pub fn weight_grad<B: Backend>(
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
}

thread_local! {
    /// One thread's unfolded band, kept between calls.
    static BAND: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Unfolds one item (`[c, h, h]`) a band of output rows at a time into this thread's band
/// buffer, handing each band's rows and columns (`c x k x k` rows of `rows x side`) to `f`.
/// A pointwise kernel's columns are the item itself, handed over whole without a copy.
fn for_each_band(item: &[f32], h: usize, taps: &Taps, mut f: impl FnMut(Range<usize>, &[f32])) {
    if taps.pointwise() {
        return f(0..h, item);
    }
    let depth = item.len() / (h * h) * taps.per_channel();
    BAND.with_borrow_mut(|band| {
        for rows in bands(depth, taps.out_side(h)) {
            unfold_item(item, h, taps, rows.clone(), band);
            f(rows, band);
        }
    });
}

impl ConvBackend for Flex {
    fn conv_taps(x: FloatTensor<Self>, weight: FloatTensor<Self>, taps: Taps) -> FloatTensor<Self> {
        let ([n, c, h, w], [o, ..]) = (x.shape().dims(), weight.shape().dims::<4>());
        if x.dtype() != DType::F32 || weight.dtype() != DType::F32 || h != w {
            return composed::conv::<Self>(x, weight, taps);
        }
        let (x, weight) = (x.to_contiguous(), weight.to_contiguous());
        let (input, weights): (&[f32], &[f32]) = (x.storage(), weight.storage());
        let (side, depth) = (taps.out_side(h), c * taps.per_channel());
        let pixels = side * side;
        // The bands cover every output row and the product overwrites them, so the output
        // needs no zeroing.
        let out = planes_from(n * o * pixels, o * pixels, |i, y| {
            let item = &input[i * c * h * h..(i + 1) * c * h * h];
            let y = y.as_mut_ptr().cast::<f32>();
            for_each_band(item, h, &taps, |rows, band| {
                let (first, cols) = (rows.start, rows.len() * side);
                // SAFETY: `y[.., first * side..]` is `o x cols` with row stride `pixels`,
                // `weights` `o x depth`, `band` `depth x cols`; not accumulating, the
                // product only writes `y`, never reads its uninitialised values.
                unsafe {
                    multiply(
                        [o, cols, depth],
                        (y.add(first * side), pixels as isize, 1),
                        false,
                        View::rows(weights.as_ptr(), depth),
                        View::rows(band.as_ptr(), cols),
                    );
                }
            });
        });
        flex_tensor(out, [n, o, side, side])
    }

    fn conv_taps_x_grad(
        grad: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        taps: Taps,
        h: usize,
    ) -> FloatTensor<Self> {
        let ([n, o, side, _], [_, c, ..]) = (grad.shape().dims(), weight.shape().dims::<4>());
        if grad.dtype() != DType::F32 || weight.dtype() != DType::F32 {
            return composed::x_grad::<Self>(grad, weight, taps, h);
        }
        if taps.stride == 1 && 2 * taps.padding == taps.dilation * (taps.kernel - 1) {
            // A stride-1 convolution that keeps the side: its input's gradient is the output's
            // gradient convolved with the weights flipped and their channels swapped, the
            // forward path (a gather) instead of folding columns back (a scatter-add).
            let weight = weight.to_contiguous();
            let flipped = flip_channels(weight.storage(), [o, c, taps.kernel]);
            return Self::conv_taps(
                grad,
                flex_tensor(flipped, [c, o, taps.kernel, taps.kernel]),
                taps,
            );
        }
        let (grad, weight) = (grad.to_contiguous(), weight.to_contiguous());
        let (grads, weights): (&[f32], &[f32]) = (grad.storage(), weight.storage());
        let (pixels, depth, per_channel) =
            (side * side, c * taps.per_channel(), taps.per_channel());
        // Folding adds into each item's planes: zeroed by the thread that folds them.
        let planes = planes_from(n * c * h * h, c * h * h, |i, item| {
            let (item, dy) = (zeroed(item), &grads[i * o * pixels..(i + 1) * o * pixels]);
            BAND.with_borrow_mut(|band| {
                for rows in bands(depth, side) {
                    let (first, cols) = (rows.start, rows.len() * side);
                    band.resize(depth * cols, 0.0);
                    // SAFETY: `band` is `depth x cols`; the weights' transpose is `depth x
                    // o` (row stride 1, column stride `depth`); `dy[.., first * side..]`
                    // is `o x cols` with row stride `pixels`.
                    unsafe {
                        multiply(
                            [depth, cols, o],
                            (band.as_mut_ptr(), cols as isize, 1),
                            false,
                            View::columns(weights.as_ptr(), depth),
                            View::rows(dy.as_ptr().add(first * side), pixels),
                        );
                    }
                    for (plane, columns) in item
                        .chunks_exact_mut(h * h)
                        .zip(band.chunks_exact(per_channel * cols))
                    {
                        fold_channel(columns, h, &taps, rows.clone(), plane);
                    }
                }
            });
        });
        flex_tensor(planes, [n, c, h, h])
    }

    fn conv_taps_weight_grad(
        x: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        taps: Taps,
    ) -> FloatTensor<Self> {
        let ([_, c, h, w], [_, o, side, _]) = (x.shape().dims(), grad.shape().dims());
        if x.dtype() != DType::F32 || grad.dtype() != DType::F32 || h != w {
            return composed::weight_grad::<Self>(x, grad, taps);
        }
        let (x, grad) = (x.to_contiguous(), grad.to_contiguous());
        let (input, grads): (&[f32], &[f32]) = (x.storage(), grad.storage());
        let (pixels, depth) = (side * side, c * taps.per_channel());
        let k = taps.kernel;
        // Each item's gradient apart, then summed in item order: a sum over however rayon
        // split the items would round differently from run to run.
        let per_item: Vec<Vec<f32>> = input
            .par_chunks(c * h * h)
            .zip(grads.par_chunks(o * pixels))
            .map(|(item, dy)| {
                let mut sum = vec![0.0f32; o * depth];
                for_each_band(item, h, &taps, |rows, band| {
                    let (first, cols) = (rows.start, rows.len() * side);
                    // SAFETY: `sum` is `o x depth`; `dy[.., first * side..]` is `o x cols` with
                    // row stride `pixels`; the band's transpose is `cols x depth` (row stride 1,
                    // column stride `cols`).
                    unsafe {
                        multiply(
                            [o, depth, cols],
                            (sum.as_mut_ptr(), depth as isize, 1),
                            true,
                            View::rows(dy.as_ptr().add(first * side), pixels),
                            View::columns(band.as_ptr(), cols),
                        );
                    }
                });
                sum
            })
            .collect();
        let mut summed = vec![0.0f32; o * depth];
        for item in &per_item {
            summed.iter_mut().zip(item).for_each(|(s, v)| *s += v);
        }
        flex_tensor(summed, [o, c, k, k])
    }
}

/// Weights `[o, c, k, k]` as `[c, o, k, k]`, each kernel turned half a turn.
fn flip_channels(weights: &[f32], [o, c, k]: [usize; 3]) -> Vec<f32> {
    let mut flipped = vec![0.0f32; weights.len()];
    for (index, value) in flipped.iter_mut().enumerate() {
        let (ci, rest) = (index / (o * k * k), index % (o * k * k));
        let (co, tap) = (rest / (k * k), rest % (k * k));
        *value = weights[(co * c + ci) * k * k + (k * k - 1 - tap)];
    }
    flipped
}

/// One item's channels (`[c, h, h]`) unfolded for the output rows `rows` into `band`
/// (`c x k x k` rows of `rows x side` pixels).
pub(crate) fn unfold_item(
    item: &[f32],
    h: usize,
    taps: &Taps,
    rows: Range<usize>,
    band: &mut Vec<f32>,
) {
    let per_channel = taps.per_channel() * rows.len() * taps.out_side(h);
    // Every value is written, so what the buffer held before need not be cleared.
    band.resize(item.len() / (h * h) * per_channel, 0.0);
    for (plane, out) in item
        .chunks_exact(h * h)
        .zip(band.chunks_exact_mut(per_channel))
    {
        unfold_channel(plane, h, taps, rows.clone(), out);
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
