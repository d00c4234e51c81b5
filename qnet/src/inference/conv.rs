//! One convolution of the inference form: its batch norm folded in, run as one matrix product
//! (the `gemm` crate, the one burn's CPU backend multiplies with) of its weights with the
//! input unfolded into columns, then bias and ReLU in one pass over the output.

use burn::nn::conv::Conv2d;
use burn::nn::{BatchNorm, PaddingConfig2d};
use burn::prelude::*;

use crate::error::QNetError;
use crate::gemm_conv::{Taps, View, bands, multiply, unfold_item};

/// A square convolution over one image `[channels_in, h, h]`, row-major, written to
/// `[channels_out, h_out, h_out]`.
#[derive(Clone, Debug)]
pub struct FoldedConv {
    /// `[channels_out, channels_in x k x k]`, rows in the unfolded columns' order.
    weights: Vec<f32>,
    bias: Vec<f32>,
    channels_in: usize,
    channels_out: usize,
    taps: Taps,
    relu: bool,
}

/// Scratch memory of the unfolding, kept between calls so a forward pass allocates nothing
/// once it has run.
#[derive(Default)]
pub struct Scratch {
    columns: Vec<f32>,
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
            taps: Taps {
                kernel,
                stride: conv.stride[0],
                dilation: conv.dilation[0],
                padding,
            },
            relu,
        })
    }

    pub fn channels_out(&self) -> usize {
        self.channels_out
    }

    /// Side of the output for an input of side `h`.
    pub fn out_side(&self, h: usize) -> usize {
        self.taps.out_side(h)
    }

    /// Convolves `input` (`[channels_in, h, h]`) into `out`, which must hold
    /// `channels_out x out_side(h)^2` values; returns the output side.
    pub fn run(&self, input: &[f32], h: usize, out: &mut [f32], scratch: &mut Scratch) -> usize {
        let side = self.out_side(h);
        let n = side * side;
        debug_assert_eq!(input.len(), self.channels_in * h * h);
        let out = &mut out[..self.channels_out * n];
        if self.taps.kernel == 1 && self.taps.stride == 1 && self.taps.padding == 0 {
            self.multiply(input, n, out, 0, n);
            return side;
        }
        // A band of output rows at a time, so its unfolded columns stay in the cache
        // between being written and being multiplied.
        let depth = self.channels_in * self.taps.per_channel();
        for rows in bands(depth, side) {
            let (first, pixels) = (rows.start, rows.len() * side);
            unfold_item(input, h, &self.taps, rows, &mut scratch.columns);
            self.multiply(&scratch.columns, pixels, out, first * side, n);
        }
        side
    }

    /// `out[:, at..at + pixels] = relu?(weights x columns + bias)`, where `columns` is
    /// `depth x pixels` and `out` `channels_out x n`, row-major.
    fn multiply(&self, columns: &[f32], pixels: usize, out: &mut [f32], at: usize, n: usize) {
        let depth = self.channels_in * self.taps.per_channel();
        debug_assert!(columns.len() >= depth * pixels && at + pixels <= n);
        // SAFETY: `out[.., at..]` is `channels_out x pixels` with row stride `n`, `weights`
        // `channels_out x depth`, `columns` `depth x pixels`, all alive for the call and
        // in bounds (asserted above).
        unsafe {
            multiply(
                [self.channels_out, pixels, depth],
                (out.as_mut_ptr().add(at), n as isize, 1),
                false,
                View::rows(self.weights.as_ptr(), depth),
                View::rows(columns.as_ptr(), pixels),
            );
        }
        for (plane, &b) in out.chunks_exact_mut(n).zip(&self.bias) {
            let band = &mut plane[at..at + pixels];
            if self.relu {
                band.iter_mut().for_each(|v| *v = (*v + b).max(0.0));
            } else {
                band.iter_mut().for_each(|v| *v += b);
            }
        }
    }
}
