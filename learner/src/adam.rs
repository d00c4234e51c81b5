//! Adam, one operation a parameter tensor. burn's Adam issues about fifteen tensor operations
//! for each parameter tensor (weight decay, the two moments, the step). On a GPU burn's fusion
//! joins them into one kernel but handles every operation on the host first, and the host's
//! work paces a GPU step (results/gpu.md, "The host's share of a GPU step"). Here a tensor's step
//! is one operation: on a GPU one CubeCL kernel, which took a sixth off burn's fusion's work a
//! step; on the CPU, where Adam costs next to nothing, burn's operations composed.
//!
//! The arithmetic is burn's `Adam` (`burn::optim::AdamConfig`), operation for operation:
//! weight decay added to the gradient (`p wd + g`), the moments `m b1 + g (1 - b1)` and
//! `v b2 + g² (1 - b2)`, and the step `p - lr (m c) / (sqrt(v) + eps s)` with `s = sqrt(1 -
//! b2^t)` and `c = s / (1 - b1^t)`. A tensor's first step starts from zero moments, which
//! gives burn's first step exactly. Its state is burn's `AdamState`.

use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, Flex, Scalar, backend_extension};
use burn::optim::{AdamState, AdaptiveMomentumState, LearningRate, Optimizer};
use burn::prelude::*;

use crate::config::LearningConfig;

/// burn's Adam with L2 weight decay (as `AdamConfig` with `weight_decay`), each tensor's
/// step one [`AdamBackend::adam_step`]. Wrap it in a `burn::optim::ModuleOptimizer`.
#[derive(Clone, Debug)]
pub struct Adam {
    beta_1: f32,
    beta_2: f32,
    /// burn's `AdamConfig` default.
    epsilon: f32,
    weight_decay: f32,
}

impl Adam {
    /// With burn's `AdamConfig` defaults where not given: epsilon 1e-5.
    pub fn new(beta_1: f32, beta_2: f32, weight_decay: f32) -> Self {
        Self {
            beta_1,
            beta_2,
            epsilon: 1e-5,
            weight_decay,
        }
    }

    /// The learning config's.
    pub fn of(config: &LearningConfig) -> Self {
        Self::new(config.beta_1, config.beta_2, config.weight_decay)
    }
}

impl Optimizer for Adam {
    type State<const D: usize> = AdamState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        param: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        let (time, moment_1, moment_2) = match state {
            Some(AdamState { momentum }) => {
                (momentum.time + 1, momentum.moment_1, momentum.moment_2)
            }
            None => (1, grad.zeros_like(), grad.zeros_like()),
        };
        let t = time as i32;
        let bias_correction_2 = (1.0 - self.beta_2.powi(t)).sqrt();
        let combined = bias_correction_2 / (1.0 - self.beta_1.powi(t));
        let factors = StepFactors {
            weight_decay: self.weight_decay,
            beta_1: self.beta_1,
            beta_2: self.beta_2,
            combined,
            epsilon: self.epsilon * bias_correction_2,
            lr: lr as f32,
        };
        let (param, moment_1, moment_2) = Dispatch::adam_step(
            param.into_dispatch(),
            grad.into_dispatch(),
            moment_1.into_dispatch(),
            moment_2.into_dispatch(),
            factors,
        );
        let [param, moment_1, moment_2] = [param, moment_1, moment_2].map(Tensor::from_dispatch);
        let momentum = AdaptiveMomentumState::new(time, moment_1, moment_2);
        (param, Some(AdamState::new(momentum)))
    }

    fn to_device<const D: usize>(state: Self::State<D>, device: &Device) -> Self::State<D> {
        AdamState::new(state.momentum.to_device(device))
    }
}

/// One Adam step of a parameter tensor: the new parameter and moments, from the parameter,
/// its gradient and its moments (all of one shape), and the step's factors.
#[backend_extension(Flex, Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"))]
pub trait AdamBackend: Backend {
    #[fusion(meta = |param, _grad, moment_1, moment_2, _factors| {
        (param.clone(), moment_1.clone(), moment_2.clone())
    })]
    fn adam_step(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        factors: StepFactors,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        composed::step::<Self>(param, grad, moment_1, moment_2, factors)
    }
}

impl AdamBackend for Flex {}

/// The factors of a tensor's step, worked out on the host as burn's Adam does.
#[derive(Clone, Copy, Debug)]
pub struct StepFactors {
    pub weight_decay: f32,
    pub beta_1: f32,
    pub beta_2: f32,
    /// `c`: both moments' bias corrections.
    pub combined: f32,
    /// `eps s`.
    pub epsilon: f32,
    pub lr: f32,
}

#[cfg(feature = "wgpu")]
mod kernel {
    use burn::backend::wgpu::{CubeBackend, CubeTensor};
    use burn::cubecl;
    use burn::tensor::DType;
    use cubecl::prelude::*;
    use cubecl::{CubeDim, calculate_cube_count_elemwise};

    use qnet::cube_outputs::empty_like;

    use super::{AdamBackend, StepFactors, composed};

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
        weight_decay: f32,
        beta_1: f32,
        one_minus_beta_1: f32,
        beta_2: f32,
        one_minus_beta_2: f32,
        combined: f32,
        epsilon: f32,
        lr: f32,
    ) {
        // Element i of the outputs' memory (laid out alike, densely) in each input, laid out
        // as it is: neighbouring threads write neighbouring values.
        let i = ABSOLUTE_POS;
        if i >= param_out.len() {
            terminate!();
        }
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
        let g = p * weight_decay + grad[at_g];
        let m = moment_1[at_m] * beta_1 + g * one_minus_beta_1;
        let v = moment_2[at_v] * beta_2 + g * g * one_minus_beta_2;
        let update = m * combined / (f32::sqrt(v) + epsilon);
        param_out[i] = p - update * lr;
        moment_1_out[i] = m;
        moment_2_out[i] = v;
    }

    impl AdamBackend for CubeBackend {
        fn adam_step(
            param: CubeTensor,
            grad: CubeTensor,
            moment_1: CubeTensor,
            moment_2: CubeTensor,
            f: StepFactors,
        ) -> (CubeTensor, CubeTensor, CubeTensor) {
            if param.dtype != DType::F32 {
                return composed::step::<Self>(param, grad, moment_1, moment_2, f);
            }
            // Laid out as the parameter lies: a convolution's weight held channels-last
            // (`Trainer`) stays so, as the GPU convolves it.
            let [param_out, moment_1_out, moment_2_out] = [(); 3].map(|_| empty_like(&param));
            let n = param_out.meta.shape().num_elements();
            let client = param.client.clone();
            let cube_dim = CubeDim::new(&client, n);
            let cube_count = calculate_cube_count_elemwise(&client, n, cube_dim);
            adam_kernel::launch(
                &client,
                cube_count,
                cube_dim,
                param.into_tensor_arg(),
                grad.into_tensor_arg(),
                moment_1.into_tensor_arg(),
                moment_2.into_tensor_arg(),
                param_out.clone().into_tensor_arg(),
                moment_1_out.clone().into_tensor_arg(),
                moment_2_out.clone().into_tensor_arg(),
                f.weight_decay,
                f.beta_1,
                1.0 - f.beta_1,
                f.beta_2,
                1.0 - f.beta_2,
                f.combined,
                f.epsilon,
                f.lr,
            );
            (param_out, moment_1_out, moment_2_out)
        }
    }
}

mod composed {
    use super::*;

    fn scalar(v: f32) -> Scalar {
        Scalar::Float(f64::from(v))
    }

    pub fn step<B: Backend>(
        param: FloatTensor<B>,
        grad: FloatTensor<B>,
        moment_1: FloatTensor<B>,
        moment_2: FloatTensor<B>,
        f: StepFactors,
    ) -> (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>) {
        let grad = B::float_add(
            B::float_mul_scalar(param.clone(), scalar(f.weight_decay)),
            grad,
        );
        let moment_1 = B::float_add(
            B::float_mul_scalar(moment_1, scalar(f.beta_1)),
            B::float_mul_scalar(grad.clone(), scalar(1.0 - f.beta_1)),
        );
        let moment_2 = B::float_add(
            B::float_mul_scalar(moment_2, scalar(f.beta_2)),
            B::float_mul_scalar(B::float_mul(grad.clone(), grad), scalar(1.0 - f.beta_2)),
        );
        let update = B::float_div(
            B::float_mul_scalar(moment_1.clone(), scalar(f.combined)),
            B::float_add_scalar(B::float_sqrt(moment_2.clone()), scalar(f.epsilon)),
        );
        let param = B::float_sub(param, B::float_mul_scalar(update, scalar(f.lr)));
        (param, moment_1, moment_2)
    }
}

#[cfg(test)]
mod tests {
    use burn::module::{Module, ModuleVisitor, Param};
    use burn::nn::{Linear, LinearConfig};
    use burn::optim::decay::WeightDecayConfig;
    use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
    use burn::prelude::*;

    use super::Adam;

    #[derive(Default)]
    struct Weights(Vec<f32>);

    impl ModuleVisitor for Weights {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.extend(param.val().into_data().iter::<f32>());
        }
    }

    /// Values between -1 and 1 that differ from one to the next, the same in every run
    /// (a seeded draw is shared with the tests running beside this one).
    fn wavy(n: usize, phase: f32) -> Vec<f32> {
        (0..n).map(|k| (k as f32 * 0.7 + phase).sin()).collect()
    }

    /// A layer after `steps` steps of `optimiser` on a loss whose gradients change from
    /// step to step.
    fn trained(mut optimiser: ModuleOptimizer, steps: usize) -> Vec<f32> {
        let device = Device::flex().autodiff();
        let mut layer: Linear = LinearConfig::new(5, 3).init(&device);
        let tensor = |values, shape: [usize; 2]| {
            Tensor::<2>::from_data(TensorData::new(values, shape), &device)
        };
        layer.weight = Param::from_tensor(tensor(wavy(15, 0.0), [5, 3]));
        let bias = TensorData::new(wavy(3, 1.0), [3]);
        layer.bias = Some(Param::from_tensor(Tensor::from_data(bias, &device)));
        for step in 0..steps {
            let x = tensor(wavy(20, step as f32), [4, 5]).mul_scalar(step as f32 + 1.0);
            let loss = layer.forward(x).powf_scalar(2.0).sum();
            let grads = GradientsParams::from_grads(loss.backward(), &layer);
            layer = optimiser.step(1e-2, layer, grads);
        }
        let mut weights = Weights::default();
        layer.visit(&mut weights);
        weights.0
    }

    #[test]
    fn steps_as_burns_adam_does() {
        let burns = AdamConfig::new()
            .with_beta_1(0.9)
            .with_beta_2(0.99)
            .with_weight_decay(Some(WeightDecayConfig::new(0.05)))
            .init();
        let ours = ModuleOptimizer::from(Adam::new(0.9, 0.99, 0.05));
        let (want, got) = (trained(burns, 4), trained(ours, 4));
        let start = trained(ModuleOptimizer::from(Adam::new(0.9, 0.99, 0.05)), 0);
        assert_eq!(want.len(), got.len());
        for ((w, g), s) in want.iter().zip(&got).zip(&start) {
            assert!(
                (w - g).abs() <= 1e-6 * w.abs().max(1e-3),
                "burn's {w}, ours {g}"
            );
            // Four steps of 1e-2 moved every weight.
            assert!((g - s).abs() > 1e-3, "{s} -> {g}");
        }
    }
}
