//! The weighted plane sums and their gradient on a GPU (CubeCL), a kernel each: a thread an
//! (item, head) summing its plane, and a thread an element of the gradient, which is laid
//! out as the maps lie.

use burn::backend::wgpu::{CubeBackend, CubeTensor};
use burn::cubecl;
use burn::tensor::Shape;
use cubecl::prelude::*;
use cubecl::{CubeCount, CubeDim};

use super::{PlaneSumBackend, composed};
use crate::cube_outputs::{all_f32, empty, empty_like};

/// Threads a cube.
const THREADS: u32 = 256;

/// Each (item, head)'s plane of `maps` `[n, heads, s, s]` times the item's plane of
/// `weights` `[n, 1, s, s]`, summed into `sums` `[n, heads]`.
#[cube(launch)]
fn plane_sums_kernel(maps: &Tensor<f32>, weights: &Tensor<f32>, sums: &mut Tensor<f32>) {
    let at = ABSOLUTE_POS;
    if at >= sums.len() {
        terminate!();
    }
    let (item, head) = (at / maps.shape(1), at % maps.shape(1));
    let map = item * maps.stride(0) + head * maps.stride(1);
    let weight = item * weights.stride(0);
    let mut sum = 0.0f32;
    for y in 0..maps.shape(2) {
        for x in 0..maps.shape(3) {
            let value = maps[map + y * maps.stride(2) + x * maps.stride(3)];
            sum += value * weights[weight + y * weights.stride(2) + x * weights.stride(3)];
        }
    }
    // (`sums` is contiguous: `at` is its place.)
    sums[at] = sum;
}

/// Element `i` of `maps_grad`'s memory (laid out densely, in any order): the sums' gradient
/// of its (item, head) times its item's weight at its place.
#[cube(launch)]
fn plane_sums_grad_kernel(weights: &Tensor<f32>, grad: &Tensor<f32>, maps_grad: &mut Tensor<f32>) {
    let i = ABSOLUTE_POS;
    if i >= maps_grad.len() {
        terminate!();
    }
    let item = (i / maps_grad.stride(0)) % maps_grad.shape(0);
    let head = (i / maps_grad.stride(1)) % maps_grad.shape(1);
    let y = (i / maps_grad.stride(2)) % maps_grad.shape(2);
    let x = (i / maps_grad.stride(3)) % maps_grad.shape(3);
    let g = grad[item * grad.stride(0) + head * grad.stride(1)];
    let w = weights[item * weights.stride(0) + y * weights.stride(2) + x * weights.stride(3)];
    maps_grad[i] = g * w;
}

/// Cubes for `len` threads.
fn cubes(len: usize) -> CubeCount {
    CubeCount::Static(len.div_ceil(THREADS as usize) as u32, 1, 1)
}

impl PlaneSumBackend for CubeBackend {
    fn weighted_plane_sums(maps: CubeTensor, weights: CubeTensor) -> CubeTensor {
        if !all_f32([&maps, &weights]) {
            return composed::sums::<Self>(maps, weights);
        }
        let sums = empty(
            &maps,
            Shape::from([maps.meta.shape()[0], maps.meta.shape()[1]]),
        );
        let client = maps.client.clone();
        plane_sums_kernel::launch(
            &client,
            cubes(sums.meta.shape().num_elements()),
            CubeDim::new_1d(THREADS),
            maps.into_tensor_arg(),
            weights.into_tensor_arg(),
            sums.clone().into_tensor_arg(),
        );
        sums
    }

    fn weighted_plane_sums_grad(
        maps: CubeTensor,
        weights: CubeTensor,
        grad: CubeTensor,
    ) -> CubeTensor {
        if !all_f32([&maps, &weights, &grad]) {
            return composed::grad::<Self>(maps, weights, grad);
        }
        let maps_grad = empty_like(&maps);
        let client = maps.client.clone();
        plane_sums_grad_kernel::launch(
            &client,
            cubes(maps_grad.meta.shape().num_elements()),
            CubeDim::new_1d(THREADS),
            weights.into_tensor_arg(),
            grad.into_tensor_arg(),
            maps_grad.clone().into_tensor_arg(),
        );
        maps_grad
    }
}
