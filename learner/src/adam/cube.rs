//! Adam's steps on a GPU (CubeCL): a thread an element (several past a row's cubes), writing
//! the parameter and its moments laid out as the parameter lies (a convolution's weight held
//! channels-last by `Trainer` stays so, as the GPU convolves it) and reading every input
//! through its strides. Four tensors' steps are one launch, a row of cubes a tensor.

use burn::backend::wgpu::{CubeBackend, CubeTensor};
use burn::cubecl;
use cubecl::prelude::*;
use cubecl::{CubeCount, CubeDim};

use qnet::cube_outputs::{all_f32, empty_like};

use super::{AdamBackend, StepFactors, composed};

/// Threads a cube.
const THREADS: u32 = 256;

/// A step's factors, as the kernels use them.
#[derive(CubeType, CubeLaunch, Clone, Copy)]
struct Factors {
    weight_decay: f32,
    beta_1: f32,
    one_minus_beta_1: f32,
    beta_2: f32,
    one_minus_beta_2: f32,
    combined: f32,
    epsilon: f32,
    lr: f32,
}

/// A thread's elements of one tensor's step: element `i` of the outputs' memory (laid out
/// alike, densely), found in each input laid out as it is, for `i` from the thread's place
/// along its row of cubes, a row's threads apart: neighbouring threads write neighbouring
/// values, and a row capped at the cubes a device takes still covers any tensor.
#[cube]
#[allow(clippy::too_many_arguments)]
fn step_elements(
    param: &Tensor<f32>,
    grad: &Tensor<f32>,
    moment_1: &Tensor<f32>,
    moment_2: &Tensor<f32>,
    param_out: &mut Tensor<f32>,
    moment_1_out: &mut Tensor<f32>,
    moment_2_out: &mut Tensor<f32>,
    f: &Factors,
) {
    let mut i = (CUBE_POS_X * CUBE_DIM + UNIT_POS) as usize;
    let row_threads = (CUBE_COUNT_X * CUBE_DIM) as usize;
    while i < param_out.len() {
        let mut at_p = 0usize;
        let mut at_g = 0usize;
        let mut at_m = 0usize;
        let mut at_v = 0usize;
        for d in 0..param.rank() {
            let k = (i / param_out.stride(d)) % param_out.shape(d);
            at_p += k * param.stride(d);
            at_g += k * grad.stride(d);
            at_m += k * moment_1.stride(d);
            at_v += k * moment_2.stride(d);
        }
        let p = param[at_p];
        let g = p * f.weight_decay + grad[at_g];
        let m = moment_1[at_m] * f.beta_1 + g * f.one_minus_beta_1;
        let v = moment_2[at_v] * f.beta_2 + g * g * f.one_minus_beta_2;
        let update = m * f.combined / (f32::sqrt(v) + f.epsilon);
        param_out[i] = p - update * f.lr;
        moment_1_out[i] = m;
        moment_2_out[i] = v;
        i += row_threads;
    }
}

/// One tensor's step.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn adam_kernel(
    param: &Tensor<f32>,
    grad: &Tensor<f32>,
    moment_1: &Tensor<f32>,
    moment_2: &Tensor<f32>,
    param_out: &mut Tensor<f32>,
    moment_1_out: &mut Tensor<f32>,
    moment_2_out: &mut Tensor<f32>,
    f: Factors,
) {
    step_elements(
        param,
        grad,
        moment_1,
        moment_2,
        param_out,
        moment_1_out,
        moment_2_out,
        &f,
    );
}

/// Four tensors' steps, the `y`-th row of cubes tensor `y`'s.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn adam_4_kernel(
    p0: &Tensor<f32>,
    g0: &Tensor<f32>,
    m0: &Tensor<f32>,
    v0: &Tensor<f32>,
    p0_out: &mut Tensor<f32>,
    m0_out: &mut Tensor<f32>,
    v0_out: &mut Tensor<f32>,
    p1: &Tensor<f32>,
    g1: &Tensor<f32>,
    m1: &Tensor<f32>,
    v1: &Tensor<f32>,
    p1_out: &mut Tensor<f32>,
    m1_out: &mut Tensor<f32>,
    v1_out: &mut Tensor<f32>,
    p2: &Tensor<f32>,
    g2: &Tensor<f32>,
    m2: &Tensor<f32>,
    v2: &Tensor<f32>,
    p2_out: &mut Tensor<f32>,
    m2_out: &mut Tensor<f32>,
    v2_out: &mut Tensor<f32>,
    p3: &Tensor<f32>,
    g3: &Tensor<f32>,
    m3: &Tensor<f32>,
    v3: &Tensor<f32>,
    p3_out: &mut Tensor<f32>,
    m3_out: &mut Tensor<f32>,
    v3_out: &mut Tensor<f32>,
    f: Factors,
) {
    if CUBE_POS_Y == 0 {
        step_elements(p0, g0, m0, v0, p0_out, m0_out, v0_out, &f);
    } else if CUBE_POS_Y == 1 {
        step_elements(p1, g1, m1, v1, p1_out, m1_out, v1_out, &f);
    } else if CUBE_POS_Y == 2 {
        step_elements(p2, g2, m2, v2, p2_out, m2_out, v2_out, &f);
    } else {
        step_elements(p3, g3, m3, v3, p3_out, m3_out, v3_out, &f);
    }
}

/// A tensor's operands in the kernels' order (parameter, gradient, moments, then the three
/// outputs, laid out as the parameter lies), and the outputs.
fn with_outputs([p, g, m, v]: [CubeTensor; 4]) -> ([CubeTensor; 7], [CubeTensor; 3]) {
    let outputs = [(); 3].map(|_| empty_like(&p));
    let [p_out, m_out, v_out] = outputs.clone();
    ([p, g, m, v, p_out, m_out, v_out], outputs)
}

/// Cubes along a row for a tensor of `len` elements: a thread an element, at most the 65,535
/// cubes a dimension that every device takes (threads then take several).
fn row(len: usize) -> u32 {
    len.div_ceil(THREADS as usize).min(u16::MAX as usize) as u32
}

/// The kernels' factors argument.
fn factors_arg(f: StepFactors) -> FactorsLaunch {
    FactorsLaunch::new(
        f.weight_decay,
        f.beta_1,
        1.0 - f.beta_1,
        f.beta_2,
        1.0 - f.beta_2,
        f.combined,
        f.epsilon,
        f.lr,
    )
}

impl AdamBackend for CubeBackend {
    fn adam_step(
        param: CubeTensor,
        grad: CubeTensor,
        moment_1: CubeTensor,
        moment_2: CubeTensor,
        f: StepFactors,
    ) -> (CubeTensor, CubeTensor, CubeTensor) {
        if !all_f32([&param, &grad, &moment_1, &moment_2]) {
            return composed::step::<Self>(param, grad, moment_1, moment_2, f);
        }
        let client = param.client.clone();
        let cubes = CubeCount::Static(row(param.meta.shape().num_elements()), 1, 1);
        let (operands, [param, moment_1, moment_2]) =
            with_outputs([param, grad, moment_1, moment_2]);
        let [p, g, m, v, p_out, m_out, v_out] = operands.map(|t| t.into_tensor_arg());
        adam_kernel::launch(
            &client,
            cubes,
            CubeDim::new_1d(THREADS),
            p,
            g,
            m,
            v,
            p_out,
            m_out,
            v_out,
            factors_arg(f),
        );
        (param, moment_1, moment_2)
    }

    fn adam_step_4(
        p0: CubeTensor,
        g0: CubeTensor,
        m0: CubeTensor,
        v0: CubeTensor,
        p1: CubeTensor,
        g1: CubeTensor,
        m1: CubeTensor,
        v1: CubeTensor,
        p2: CubeTensor,
        g2: CubeTensor,
        m2: CubeTensor,
        v2: CubeTensor,
        p3: CubeTensor,
        g3: CubeTensor,
        m3: CubeTensor,
        v3: CubeTensor,
        f: StepFactors,
    ) -> (
        (CubeTensor, CubeTensor, CubeTensor),
        (CubeTensor, CubeTensor, CubeTensor),
        (CubeTensor, CubeTensor, CubeTensor),
        (CubeTensor, CubeTensor, CubeTensor),
    ) {
        let client = p0.client.clone();
        let tensors = [
            [p0, g0, m0, v0],
            [p1, g1, m1, v1],
            [p2, g2, m2, v2],
            [p3, g3, m3, v3],
        ];
        // Each tensor alone (the composed step) where the kernel does not take them all.
        if !all_f32(tensors.iter().flatten()) {
            let [a, b, c, d] = tensors.map(|[p, g, m, v]| Self::adam_step(p, g, m, v, f));
            return (a, b, c, d);
        }
        let longest = tensors
            .iter()
            .map(|[p, ..]| p.meta.shape().num_elements())
            .max();
        let cubes = CubeCount::Static(row(longest.unwrap_or(0)), 4, 1);
        let [a, b, c, d] = tensors.map(with_outputs);
        let args = |operands: [CubeTensor; 7]| operands.map(|t| t.into_tensor_arg());
        let [p0, g0, m0, v0, p0o, m0o, v0o] = args(a.0);
        let [p1, g1, m1, v1, p1o, m1o, v1o] = args(b.0);
        let [p2, g2, m2, v2, p2o, m2o, v2o] = args(c.0);
        let [p3, g3, m3, v3, p3o, m3o, v3o] = args(d.0);
        adam_4_kernel::launch(
            &client,
            cubes,
            CubeDim::new_1d(THREADS),
            p0,
            g0,
            m0,
            v0,
            p0o,
            m0o,
            v0o,
            p1,
            g1,
            m1,
            v1,
            p1o,
            m1o,
            v1o,
            p2,
            g2,
            m2,
            v2,
            p2o,
            m2o,
            v2o,
            p3,
            g3,
            m3,
            v3,
            p3o,
            m3o,
            v3o,
            factors_arg(f),
        );
        let [a, b, c, d] = [a.1, b.1, c.1, d.1].map(|[p, m, v]| (p, m, v));
        (a, b, c, d)
    }
}
