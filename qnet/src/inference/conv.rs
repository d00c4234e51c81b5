//! One convolution of the inference form: its batch norm folded in, run as one matrix product
//! (the `gemm` crate, the one burn's CPU backend multiplies with) of its weights with the
//! input unfolded into columns, then bias and ReLU in one pass over the output.

use burn::nn::conv::Conv2d;
use burn::nn::{BatchNorm, PaddingConfig2d};
use burn::prelude::*;

use crate::error::QNetError;

/// A square convolution over one image `[channels_in, h, h]`, row-major, written to
/// `[channels_out, h_out, h_out]`.
#[derive(Clone, Debug)]
pub struct FoldedConv {
    /// `[channels_out, channels_in x k x k]`, rows in the unfolded columns' order.
    weights: Vec<f32>,
    bias: Vec<f32>,
    channels_in: usize,
    channels_out: usize,
    kernel: usize,
    stride: usize,
    dilation: usize,
    padding: usize,
    relu: bool,
}

/// Scratch memory of the unfolding, kept between calls so a forward pass allocates nothing
/// once it has run.
#[derive(Default)]
pub struct Scratch {
    columns: Vec<f32>,
    phases: Vec<f32>,
}

/// A tensor's values, row-major.
pub fn values<const D: usize>(tensor: Tensor<D>) -> Result<Vec<f32>, QNetError> {
    tensor
        .into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| QNetError::Weights(format!("{e:?}")))
}

/// A batch norm in inference as `x * scale + shift`, per channel.
pub fn norm_affine(norm: &BatchNorm) -> Result<(Vec<f32>, Vec<f32>), QNetError> {
    let gamma = values(norm.gamma.val())?;
    let beta = values(norm.beta.val())?;
    let mean = values(norm.running_mean.value())?;
    let var = values(norm.running_var.value())?;
    let scale: Vec<f32> = gamma
        .iter()
        .zip(&var)
        .map(|(g, v)| g / (v + norm.epsilon as f32).sqrt())
        .collect();
    let shift = beta
        .iter()
        .zip(&mean)
        .zip(&scale)
        .map(|((b, m), s)| b - m * s)
        .collect();
    Ok((scale, shift))
}

/// The padding of `conv` on every side, which must be the same.
pub fn even_padding(conv: &Conv2d) -> Result<usize, QNetError> {
    match conv.padding {
        PaddingConfig2d::Valid => Ok(0),
        PaddingConfig2d::Explicit(top, left, bottom, right)
            if top == left && left == bottom && bottom == right =>
        {
            Ok(top)
        }
        ref other => Err(QNetError::Weights(format!(
            "the inference form takes even padding on every side, not {other:?}"
        ))),
    }
}

impl FoldedConv {
    /// `conv`, then `norm` folded into its weights and bias when given, then ReLU if `relu`.
    pub fn new(conv: &Conv2d, norm: Option<&BatchNorm>, relu: bool) -> Result<Self, QNetError> {
        let [channels_out, channels_in, kernel, kernel_w] = conv.weight.dims();
        let padding = even_padding(conv)?;
        if kernel != kernel_w
            || conv.stride[0] != conv.stride[1]
            || conv.dilation[0] != conv.dilation[1]
            || conv.groups != 1
        {
            return Err(QNetError::Weights(
                "the inference form takes square, ungrouped convolutions".into(),
            ));
        }
        let mut weights = values(conv.weight.val())?;
        let mut bias = match &conv.bias {
            Some(bias) => values(bias.val())?,
            None => vec![0.0; channels_out],
        };
        if let Some(norm) = norm {
            let (scale, shift) = norm_affine(norm)?;
            let row = weights.len() / channels_out;
            for (o, (s, t)) in scale.iter().zip(&shift).enumerate() {
                weights[o * row..(o + 1) * row]
                    .iter_mut()
                    .for_each(|w| *w *= s);
                bias[o] = bias[o] * s + t;
            }
        }
        Ok(Self {
            weights,
            bias,
            channels_in,
            channels_out,
            kernel,
            stride: conv.stride[0],
            dilation: conv.dilation[0],
            padding,
            relu,
        })
    }

    pub fn channels_out(&self) -> usize {
        self.channels_out
    }

    /// Side of the output for an input of side `h`.
    pub fn out_side(&self, h: usize) -> usize {
        (h + 2 * self.padding - self.dilation * (self.kernel - 1) - 1) / self.stride + 1
    }

    /// Convolves `input` (`[channels_in, h, h]`) into `out`, which must hold
    /// `channels_out x out_side(h)^2` values; returns the output side.
    pub fn run(&self, input: &[f32], h: usize, out: &mut [f32], scratch: &mut Scratch) -> usize {
        let side = self.out_side(h);
        let n = side * side;
        let depth = self.channels_in * self.kernel * self.kernel;
        debug_assert_eq!(input.len(), self.channels_in * h * h);
        let out = &mut out[..self.channels_out * n];
        let columns: &[f32] = if self.kernel == 1 && self.stride == 1 && self.padding == 0 {
            input
        } else {
            self.unfold(input, h, side, scratch);
            &scratch.columns
        };
        // SAFETY: `out` is `channels_out x n`, `weights` `channels_out x depth`, `columns`
        // `depth x n`, all row-major and alive for the call; strides are in elements.
        unsafe {
            gemm::gemm(
                self.channels_out,
                n,
                depth,
                out.as_mut_ptr(),
                1,
                n as isize,
                false,
                self.weights.as_ptr(),
                1,
                depth as isize,
                columns.as_ptr(),
                1,
                n as isize,
                0.0,
                1.0,
                false,
                false,
                false,
                gemm::Parallelism::None,
            );
        }
        for (plane, &b) in out.chunks_exact_mut(n).zip(&self.bias) {
            if self.relu {
                plane.iter_mut().for_each(|v| *v = (*v + b).max(0.0));
            } else {
                plane.iter_mut().for_each(|v| *v += b);
            }
        }
        side
    }

    /// Fills `scratch.columns` with the input unfolded: row `(c, ky, kx)` holds, for each
    /// output pixel, the input pixel under that tap (zero in the padding). A strided
    /// convolution first splits each input row into its `stride` phases (columns `j`, `j +
    /// stride`, ...) so that every tap's row is a contiguous copy.
    fn unfold(&self, input: &[f32], h: usize, side: usize, scratch: &mut Scratch) {
        let (k, s, d, pad) = (self.kernel, self.stride, self.dilation, self.padding);
        let n = side * side;
        let phase_width = h.div_ceil(s);
        let phases: &[f32] = if s == 1 {
            input
        } else {
            let plane = h * phase_width;
            // Every value read below is written first.
            scratch.phases.resize(s * self.channels_in * plane, 0.0);
            for (r, row) in input.chunks_exact(h).enumerate() {
                for (j, taps) in row.chunks(s).enumerate() {
                    for (phase, &v) in taps.iter().enumerate() {
                        scratch.phases[phase * self.channels_in * plane + r * phase_width + j] = v;
                    }
                }
            }
            &scratch.phases
        };
        let columns = &mut scratch.columns;
        // Every value below is written, so what the buffer held before need not be cleared.
        columns.resize(self.channels_in * k * k * n, 0.0);
        for c in 0..self.channels_in {
            for ky in 0..k {
                for kx in 0..k {
                    let row = &mut columns[((c * k + ky) * k + kx) * n..][..n];
                    // Output columns whose tap falls inside the image: [lo, hi).
                    let shift = (kx * d) as isize - pad as isize;
                    let lo = ((-shift).max(0) as usize).div_ceil(s).min(side);
                    let last = h as isize - 1 - shift;
                    let hi = if last < 0 {
                        0
                    } else {
                        (last as usize / s + 1).min(side)
                    };
                    let first = (lo * s) as isize + shift;
                    for (oy, out_row) in row.chunks_exact_mut(side).enumerate() {
                        let iy = (oy * s + ky * d) as isize - pad as isize;
                        if lo >= hi || iy < 0 || iy >= h as isize {
                            out_row.fill(0.0);
                            continue;
                        }
                        let (phase, start) = (first as usize % s, first as usize / s);
                        let base = ((phase * self.channels_in + c) * h + iy as usize) * phase_width
                            + start;
                        out_row[..lo].fill(0.0);
                        out_row[lo..hi].copy_from_slice(&phases[base..base + hi - lo]);
                        out_row[hi..].fill(0.0);
                    }
                }
            }
        }
    }
}
