//! Where a convolution's taps fall ([`Taps`]), and an input unfolded into the columns of
//! its matrix product (im2col) and folded back (col2im).

use std::ops::Range;

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
    pub(super) fn pointwise(&self) -> bool {
        self.kernel == 1 && self.stride == 1 && self.padding == 0
    }

    /// For the tap `kx` columns to the right, the output columns whose input column lies
    /// inside an image of side `h`, `[lo, hi)`, and the input column of the first of them.
    pub(super) fn inside(&self, kx: usize, h: usize, side: usize) -> (usize, usize, usize) {
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
    pub(super) fn source_row(&self, ky: usize, oy: usize, h: usize) -> Option<usize> {
        let iy = (oy * self.stride + ky * self.dilation) as isize - self.padding as isize;
        (0..h as isize).contains(&iy).then_some(iy as usize)
    }
}

/// Unfolds one channel `plane` (`h x h`) for the output rows `rows`: `out` gets a row per tap
/// `(ky, kx)`, each holding, for every pixel of those output rows, the input pixel under the
/// tap (zero in the padding).
pub(super) fn unfold_channel(
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

/// The reverse of [`unfold_channel`]: adds each tap row of `columns` (the output rows `rows`)
/// back onto the input pixel it was taken from, into `plane` (`h x h`).
pub(super) fn fold_channel(
    columns: &[f32],
    h: usize,
    taps: &Taps,
    rows: Range<usize>,
    plane: &mut [f32],
) {
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
