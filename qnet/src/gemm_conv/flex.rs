//! The convolution on the CPU backend: its forward and both gradients as loops over bands of
//! unfolded columns, each item on its own thread.

use std::ops::Range;

use burn::backend::Flex;
use burn::backend::TensorMetadata;
use burn::backend::tensor::FloatTensor;
use burn::tensor::DType;
use rayon::prelude::*;

use super::columns::{fold_channel, unfold_item};
use super::multiply::{View, bands, flex_tensor, multiply};
use super::{ConvBackend, Taps, composed};
use crate::fresh::{planes_from, zeroed};

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
