//! A square convolution's input unfolded into columns (im2col), as one differentiable
//! operation whose backward folds the columns' gradient back onto the input (col2im).
//!
//! Training convolves as one matrix product of the weights with these columns
//! ([`crate::net`]). burn has no such operation, and composed from its own (pad, then a gather
//! over precomputed taps) the gather and its scatter-add backward ran element by element on
//! one core. So it is a backend extension: on the CPU backend both directions are plain loops
//! over the batch's planes, spread over the cores, the same loops the inference form unfolds
//! with; on any other backend (wgpu) the composed version, which autodiff differentiates
//! through the same backward.

use std::ops::Range;

use burn::backend::TensorMetadata;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, unary};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::prelude::*;
use burn::tensor::{DType, IndexingUpdateOp, Shape, TensorData};
use rayon::prelude::*;

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
pub(crate) fn unfold_channel(
    plane: &[f32],
    h: usize,
    taps: &Taps,
    rows: Range<usize>,
    out: &mut [f32],
) {
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

/// The reverse of [`unfold_channel`] over every output row: adds each tap row of `columns`
/// back onto the input pixel it was taken from, into `plane` (`h x h`).
fn fold_channel(columns: &[f32], h: usize, taps: &Taps, plane: &mut [f32]) {
    let side = taps.out_side(h);
    let n = side * side;
    let k = taps.kernel;
    for ky in 0..k {
        for kx in 0..k {
            let row = &columns[(ky * k + kx) * n..][..n];
            let (lo, hi, first) = taps.inside(kx, h, side);
            if lo >= hi {
                continue;
            }
            for (oy, grad_row) in row.chunks_exact(side).enumerate() {
                if let Some(iy) = taps.source_row(ky, oy, h) {
                    let target = &mut plane[iy * h + first..(iy + 1) * h];
                    for (t, &g) in target
                        .iter_mut()
                        .step_by(taps.stride)
                        .zip(&grad_row[lo..hi])
                    {
                        *t += g;
                    }
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

/// The unfolding as a backend operation.
#[backend_extension(Flex, Autodiff, Cube: cfg(feature = "wgpu"))]
pub trait UnfoldBackend: Backend {
    /// `x` `[n, c, h, h]` unfolded to `[n, c x k x k, side^2]`, rows in the `(channel, kernel
    /// row, kernel column)` order of a convolution's weights.
    fn unfold_taps(x: FloatTensor<Self>, taps: Taps) -> FloatTensor<Self> {
        composed::unfold::<Self>(x, taps)
    }

    /// The gradient of [`UnfoldBackend::unfold_taps`]: `columns`' gradient folded back to
    /// `[n, c, h, h]`.
    fn fold_taps(
        columns: FloatTensor<Self>,
        taps: Taps,
        channels: usize,
        h: usize,
    ) -> FloatTensor<Self> {
        composed::fold::<Self>(columns, taps, channels, h)
    }
}

/// The unfolding composed from burn's own operations, for every backend: the input padded by
/// one zero pixel at the end of each plane's row-major values, and every tap an index into
/// them.
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
            &[
                burn::tensor::Slice::from(0..n * channels),
                burn::tensor::Slice::from(0..h * h),
            ],
        );
        B::float_reshape(planes, Shape::new([n, channels, h, h]))
    }
}

impl UnfoldBackend for Flex {
    fn unfold_taps(x: FloatTensor<Self>, taps: Taps) -> FloatTensor<Self> {
        let [n, c, h, w] = x.shape().dims();
        if x.dtype() != DType::F32 || h != w {
            return composed::unfold::<Self>(x, taps);
        }
        let x = x.to_contiguous();
        let input: &[f32] = x.storage();
        let side = taps.out_side(h);
        let per_plane = taps.per_channel() * side * side;
        let mut columns = vec![0.0f32; n * c * per_plane];
        columns
            .par_chunks_mut(per_plane)
            .zip(input.par_chunks(h * h))
            .for_each(|(out, plane)| unfold_channel(plane, h, &taps, 0..side, out));
        let shape = [n, c * taps.per_channel(), side * side];
        <Self as FloatTensorOps<Self>>::float_from_data(
            TensorData::new(columns, shape),
            &Default::default(),
        )
    }

    fn fold_taps(
        columns: FloatTensor<Self>,
        taps: Taps,
        channels: usize,
        h: usize,
    ) -> FloatTensor<Self> {
        if columns.dtype() != DType::F32 {
            return composed::fold::<Self>(columns, taps, channels, h);
        }
        let [n, _, _] = columns.shape().dims();
        let columns = columns.to_contiguous();
        let values: &[f32] = columns.storage();
        let side = taps.out_side(h);
        let per_plane = taps.per_channel() * side * side;
        let mut planes = vec![0.0f32; n * channels * h * h];
        planes
            .par_chunks_mut(h * h)
            .zip(values.par_chunks(per_plane))
            .for_each(|(plane, columns)| fold_channel(columns, h, &taps, plane));
        <Self as FloatTensorOps<Self>>::float_from_data(
            TensorData::new(planes, [n, channels, h, h]),
            &Default::default(),
        )
    }
}

#[cfg(feature = "wgpu")]
impl UnfoldBackend for burn::backend::Cube {}

impl<B: Backend + UnfoldBackend, C: CheckpointStrategy> UnfoldBackend for Autodiff<B, C> {
    fn unfold_taps(x: FloatTensor<Self>, taps: Taps) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct Fold;

        impl<B: Backend + UnfoldBackend> Backward<B, 1> for Fold {
            /// The taps, the input's channels and side.
            type State = (Taps, usize, usize);

            fn backward(
                self,
                ops: Ops<Self::State, 1>,
                grads: &mut Gradients,
                _checkpointer: &mut Checkpointer,
            ) {
                let (taps, channels, h) = ops.state;
                unary::<B, _>(ops.parents, ops.node, grads, |grad| {
                    B::fold_taps(grad, taps, channels, h)
                });
            }
        }

        let [_, channels, h, _] = x.primitive().shape().dims();
        match Fold.prepare::<C>([x.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => prep.finish(
                (taps, channels, h),
                B::unfold_taps(x.into_primitive(), taps),
            ),
            OpsKind::UnTracked(prep) => prep.finish(B::unfold_taps(x.into_primitive(), taps)),
        }
    }
}

/// [`UnfoldBackend::unfold_taps`] on a tensor of any backend the build has.
pub fn unfold(x: Tensor<4>, taps: Taps) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as UnfoldBackend>::unfold_taps(
        x.into_dispatch(),
        taps,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flex(values: Vec<f32>, shape: [usize; 4]) -> FloatTensor<Flex> {
        <Flex as FloatTensorOps<Flex>>::float_from_data(
            TensorData::new(values, shape),
            &Default::default(),
        )
    }

    fn values(tensor: FloatTensor<Flex>) -> Vec<f32> {
        tensor.into_data().try_to_vec::<f32>().unwrap()
    }

    #[test]
    fn the_cpu_loops_equal_the_composed_unfolding_and_fold_every_way_the_nets_convolve() {
        // An odd side, so a stride-2 row ends on a tap that lacks its pair.
        let (n, c, h) = (2, 3, 9);
        let input: Vec<f32> = (0..n * c * h * h)
            .map(|i| (i as f32 * 0.37).sin())
            .collect();
        for (stride, dilation) in [(2, 1), (1, 1), (1, 2)] {
            let taps = Taps {
                kernel: 3,
                stride,
                dilation,
                padding: dilation,
            };
            let ours = values(Flex::unfold_taps(flex(input.clone(), [n, c, h, h]), taps));
            let composed = values(composed::unfold::<Flex>(
                flex(input.clone(), [n, c, h, h]),
                taps,
            ));
            assert_eq!(
                ours, composed,
                "unfold, stride {stride}, dilation {dilation}"
            );
            let side = taps.out_side(h);
            let gradient: Vec<f32> = (0..n * c * 9 * side * side)
                .map(|i| (i as f32 * 0.11).cos())
                .collect();
            let columns = || {
                <Flex as FloatTensorOps<Flex>>::float_from_data(
                    TensorData::new(gradient.clone(), [n, c * 9, side * side]),
                    &Default::default(),
                )
            };
            let ours = values(Flex::fold_taps(columns(), taps, c, h));
            let composed = values(composed::fold::<Flex>(columns(), taps, c, h));
            let worst = ours
                .iter()
                .zip(&composed)
                .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(
                worst < 1e-5,
                "fold, stride {stride}, dilation {dilation}: {worst}"
            );
        }
    }
}
