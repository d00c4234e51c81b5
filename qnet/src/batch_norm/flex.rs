//! The operation on the CPU backend: the statistics, the normalisation with its ReLU and
//! the three gradients as loops over each channel's planes.

use burn::backend::tensor::FloatTensor;
use burn::backend::{Flex, TensorMetadata};
use burn::tensor::DType;

use rayon::prelude::*;

use crate::fresh::planes_from;
use crate::gemm_conv::flex_tensor;

use super::{NormBackend, Statistics, composed};

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
    fn norm_statistics(
        x: FloatTensor<Self>,
        running_mean: FloatTensor<Self>,
        running_variance: FloatTensor<Self>,
        momentum: f64,
    ) -> Statistics<Self> {
        let running = [running_mean, running_variance];
        let Some([c, m]) = layout(&x) else {
            return composed::with_running::<Self>(
                composed::statistics::<Self>(x),
                running,
                momentum,
            );
        };
        let x = x.to_contiguous();
        let values: &[f32] = x.storage();
        let (mean, variance): (Vec<f32>, Vec<f32>) = (0..c)
            .into_par_iter()
            .map(|k| moments(values, c, m, k))
            .unzip();
        // The update on `[c]` values: burn's operations, as the composed operation's.
        composed::with_running::<Self>(
            (flex_tensor(mean, vec![c]), flex_tensor(variance, vec![c])),
            running,
            momentum,
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
        let Some([c, m]) = layout(&x) else {
            return composed::train::<Self>(x, gamma, beta, mean, variance, epsilon);
        };
        let shape = x.shape().to_vec();
        let tensors = [x, gamma, beta, mean, variance].map(|t| t.to_contiguous());
        let [values, gamma, beta, mean, variance]: [&[f32]; 5] =
            tensors.each_ref().map(|t| t.storage());
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
        mean: FloatTensor<Self>,
        variance: FloatTensor<Self>,
        epsilon: f64,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let Some([c, m]) = layout(&x) else {
            return composed::grads::<Self>(x, gamma, mean, variance, epsilon, output, grad);
        };
        let shape = x.shape().to_vec();
        let tensors = [x, gamma, mean, variance, output, grad].map(|t| t.to_contiguous());
        let [values, gamma, mean, variance, y, grad]: [&[f32]; 6] =
            tensors.each_ref().map(|t| t.storage());
        // The gradient through the ReLU: none where it cut the value to 0.
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
                let (mean, variance) = (mean[k], variance[k]);
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
