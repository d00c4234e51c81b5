//! The matrix product of a convolution's weights with its columns, a band of output rows
//! at a time so the columns stay in the cache.

use std::ops::Range;

use burn::backend::Flex;
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::tensor::{Shape, TensorData};

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
