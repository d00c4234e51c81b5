//! How a convolution weight lies in memory: as burn lays it out, `[out, in, kh, kw]`, or
//! channels-last, `[out, kh, kw, in]`, as burn-cubecl convolves it (`channels_last`).

/// A convolution weight's `[out, in, kh, kw]` permuted to `[out, kh, kw, in]`, and back.
pub(crate) const TO_CHANNELS_LAST: [usize; 4] = [0, 2, 3, 1];
pub(crate) const FROM_CHANNELS_LAST: [usize; 4] = [0, 3, 1, 2];

/// Four axes as the axes of a `D`-dimensional permute, for code generic over `D` that
/// permutes only where `D` is 4.
pub(crate) fn axes<const D: usize>(four: [usize; 4]) -> [usize; D] {
    let mut all = [0; D];
    all.copy_from_slice(&four);
    all
}

/// Whether a tensor of `dims` is a convolution weight, which nets on a GPU hold
/// channels-last: the nets' only four-dimensional tensors.
pub(crate) fn held_channels_last(dims: &[usize]) -> bool {
    dims.len() == 4
}
