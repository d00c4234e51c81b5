//! Adam over a module's parameters, four parameter tensors an operation. burn's Adam issues
//! about fifteen tensor operations for each parameter tensor (weight decay, the two moments,
//! the step). On a GPU burn's fusion joins them into one kernel but handles every operation on
//! the host first, and the host's work paces a GPU step (results/gpu.md, "The host's share of
//! a GPU step"). Here four tensors' steps are one operation: on a GPU one CubeCL kernel (a
//! kernel a tensor before: 25 a step of the shipped nets, now 7); on the CPU, where Adam
//! costs next to nothing, burn's operations composed, a tensor at a time.
//!
//! The arithmetic is burn's `Adam` (`burn::optim::AdamConfig`), operation for operation:
//! weight decay added to the gradient (`p wd + g`), the moments `m b1 + g (1 - b1)` and
//! `v b2 + g² (1 - b2)`, and the step `p - lr (m c) / (sqrt(v) + eps s)` with `s = sqrt(1 -
//! b2^t)` and `c = s / (1 - b1^t)`. A tensor's first step starts from zero moments, which
//! gives burn's first step exactly.

#[cfg(feature = "wgpu")]
mod cube;

use std::collections::{BTreeMap, HashMap};

use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, Flex, Scalar, backend_extension};
use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::optim::GradientsParams;
use burn::prelude::*;

use crate::config::LearningConfig;

/// Parameter tensors a [`AdamBackend::adam_step_4`]: four tensors' seven operands each fit
/// the 31 bindings burn's fusion takes any device to have.
const TENSORS_AN_OPERATION: usize = 4;

/// burn's Adam with L2 weight decay (as `AdamConfig` with `weight_decay`), and each
/// parameter's moments.
#[derive(Clone, Debug)]
pub struct Adam {
    beta_1: f32,
    beta_2: f32,
    /// burn's `AdamConfig` default.
    epsilon: f32,
    weight_decay: f32,
    moments: HashMap<ParamId, Moments>,
}

/// A parameter's steps so far and its two moments.
#[derive(Clone, Debug)]
struct Moments {
    steps: i32,
    first: FloatTensor<Dispatch>,
    second: FloatTensor<Dispatch>,
}

/// A parameter to step: its value (without autodiff), its gradient and its moments.
struct Stepping {
    id: ParamId,
    param: FloatTensor<Dispatch>,
    grad: FloatTensor<Dispatch>,
    moments: Moments,
}

impl Adam {
    /// With burn's `AdamConfig` defaults where not given: epsilon 1e-5.
    pub fn new(beta_1: f32, beta_2: f32, weight_decay: f32) -> Self {
        Self {
            beta_1,
            beta_2,
            epsilon: 1e-5,
            weight_decay,
            moments: HashMap::new(),
        }
    }

    /// The learning config's.
    pub fn of(config: &LearningConfig) -> Self {
        Self::new(config.beta_1, config.beta_2, config.weight_decay)
    }

    /// One step of every parameter of `module` that `grads` holds a gradient for, at
    /// learning rate `lr`; the others are left as they are.
    pub fn step<M: Module>(&mut self, lr: f64, module: M, mut grads: GradientsParams) -> M {
        let mut gather = Gather {
            grads: &mut grads,
            moments: &mut self.moments,
            found: Vec::new(),
        };
        module.visit(&mut gather);
        let found = gather.found;
        let mut stepped = HashMap::with_capacity(found.len());
        // Tensors step together when they have taken as many steps (in a run, all of them).
        let mut by_steps: BTreeMap<i32, Vec<Stepping>> = BTreeMap::new();
        for s in found {
            by_steps.entry(s.moments.steps).or_default().push(s);
        }
        for (steps, group) in by_steps {
            let steps = steps + 1;
            let factors = self.factors(steps, lr);
            let mut group = group.into_iter().peekable();
            while group.peek().is_some() {
                let chunk = group.by_ref().take(TENSORS_AN_OPERATION).collect();
                for (id, (param, first, second)) in step_tensors(chunk, factors) {
                    let moments = Moments {
                        steps,
                        first,
                        second,
                    };
                    self.moments.insert(id, moments);
                    stepped.insert(id, param);
                }
            }
        }
        module.map(&mut Put(stepped))
    }

    /// The factors of step `t` (from 1), worked out as burn's Adam does.
    fn factors(&self, t: i32, lr: f64) -> StepFactors {
        let bias_correction_2 = (1.0 - self.beta_2.powi(t)).sqrt();
        StepFactors {
            weight_decay: self.weight_decay,
            beta_1: self.beta_1,
            beta_2: self.beta_2,
            combined: bias_correction_2 / (1.0 - self.beta_1.powi(t)),
            epsilon: self.epsilon * bias_correction_2,
            lr: lr as f32,
        }
    }
}

/// A parameter tensor's new value and moments.
type Stepped = (
    FloatTensor<Dispatch>,
    FloatTensor<Dispatch>,
    FloatTensor<Dispatch>,
);

/// The new parameter and moments of each of at most [`TENSORS_AN_OPERATION`] tensors, by
/// parameter: one operation for a full four, one a tensor for fewer.
fn step_tensors(chunk: Vec<Stepping>, f: StepFactors) -> Vec<(ParamId, Stepped)> {
    let ids: Vec<ParamId> = chunk.iter().map(|s| s.id).collect();
    let stepped = match <[Stepping; TENSORS_AN_OPERATION]>::try_from(chunk) {
        Ok([a, b, c, d]) => {
            let (a, b, c, d) = Dispatch::adam_step_4(
                a.param,
                a.grad,
                a.moments.first,
                a.moments.second,
                b.param,
                b.grad,
                b.moments.first,
                b.moments.second,
                c.param,
                c.grad,
                c.moments.first,
                c.moments.second,
                d.param,
                d.grad,
                d.moments.first,
                d.moments.second,
                f,
            );
            vec![a, b, c, d]
        }
        Err(fewer) => fewer
            .into_iter()
            .map(|s| Dispatch::adam_step(s.param, s.grad, s.moments.first, s.moments.second, f))
            .collect(),
    };
    ids.into_iter().zip(stepped).collect()
}

/// Finds the parameters `grads` holds a gradient for, with their moments (zero for a
/// parameter's first step).
struct Gather<'a> {
    grads: &'a mut GradientsParams,
    moments: &'a mut HashMap<ParamId, Moments>,
    found: Vec<Stepping>,
}

impl ModuleVisitor for Gather<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let Some(grad) = self.grads.remove::<D>(param.id) else {
            return;
        };
        let moments = self.moments.remove(&param.id).unwrap_or_else(|| Moments {
            steps: 0,
            first: grad.zeros_like().into_dispatch(),
            second: grad.zeros_like().into_dispatch(),
        });
        self.found.push(Stepping {
            id: param.id,
            param: param.val().inner().into_dispatch(),
            grad: grad.into_dispatch(),
            moments,
        });
    }
}

/// Puts each stepped parameter's new value in its place, tracked as the old one was (as
/// burn's `ModuleOptimizer` restores it).
struct Put(HashMap<ParamId, FloatTensor<Dispatch>>);

impl ModuleMapper for Put {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let Some(value) = self.0.remove(&param.id) else {
            return param;
        };
        let (id, old, mapper) = param.consume();
        let mut new = Tensor::from_inner(Tensor::<D>::from_dispatch(value));
        if let Some(strategy) = old.gradient_checkpointing_strategy() {
            new = new.with_gradient_checkpointing_strategy(strategy);
        }
        if old.is_require_grad() {
            new = new.require_grad();
        }
        Param::from_mapped_value(id, new, mapper)
    }
}

/// One Adam step of parameter tensors: the new parameter and moments, from the parameter,
/// its gradient and its moments (all of one shape), and the step's factors.
#[backend_extension(Flex, Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"))]
pub trait AdamBackend: Backend {
    /// One tensor's step.
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

    /// Four tensors' steps, each as [`AdamBackend::adam_step`]'s, in one operation.
    #[fusion(meta = |p0, _g0, m0, v0, p1, _g1, m1, v1, p2, _g2, m2, v2, p3, _g3, m3, v3, _f| {
        (
            (p0.clone(), m0.clone(), v0.clone()),
            (p1.clone(), m1.clone(), v1.clone()),
            (p2.clone(), m2.clone(), v2.clone()),
            (p3.clone(), m3.clone(), v3.clone()),
        )
    })]
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    fn adam_step_4(
        p0: FloatTensor<Self>,
        g0: FloatTensor<Self>,
        m0: FloatTensor<Self>,
        v0: FloatTensor<Self>,
        p1: FloatTensor<Self>,
        g1: FloatTensor<Self>,
        m1: FloatTensor<Self>,
        v1: FloatTensor<Self>,
        p2: FloatTensor<Self>,
        g2: FloatTensor<Self>,
        m2: FloatTensor<Self>,
        v2: FloatTensor<Self>,
        p3: FloatTensor<Self>,
        g3: FloatTensor<Self>,
        m3: FloatTensor<Self>,
        v3: FloatTensor<Self>,
        factors: StepFactors,
    ) -> (
        (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>),
        (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>),
        (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>),
        (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>),
    ) {
        (
            composed::step::<Self>(p0, g0, m0, v0, factors),
            composed::step::<Self>(p1, g1, m1, v1, factors),
            composed::step::<Self>(p2, g2, m2, v2, factors),
            composed::step::<Self>(p3, g3, m3, v3, factors),
        )
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
    use burn::optim::{AdamConfig, GradientsParams};
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

    /// Three layers (six parameter tensors: a full four stepped together and two alone),
    /// after `steps` steps of `step` on a loss whose gradients change from step to step.
    fn trained(
        mut step: impl FnMut(Vec<Linear>, GradientsParams) -> Vec<Linear>,
        steps: usize,
    ) -> Vec<f32> {
        let device = Device::flex().autodiff();
        let tensor = |values, shape: [usize; 2]| {
            Tensor::<2>::from_data(TensorData::new(values, shape), &device)
        };
        let mut layers: Vec<Linear> = (0..3)
            .map(|k| {
                let mut layer: Linear = LinearConfig::new(5, 5).init(&device);
                layer.weight = Param::from_tensor(tensor(wavy(25, k as f32), [5, 5]));
                let bias = TensorData::new(wavy(5, 1.0 + k as f32), [5]);
                layer.bias = Some(Param::from_tensor(Tensor::from_data(bias, &device)));
                layer
            })
            .collect();
        for step_index in 0..steps {
            let x = tensor(wavy(20, step_index as f32), [4, 5]).mul_scalar(step_index as f32 + 1.0);
            let y = layers.iter().fold(x, |x, layer| layer.forward(x).tanh());
            let loss = y.powf_scalar(2.0).sum();
            let grads = GradientsParams::from_grads(loss.backward(), &layers);
            layers = step(layers, grads);
        }
        let mut weights = Weights::default();
        layers.visit(&mut weights);
        weights.0
    }

    #[test]
    fn steps_as_burns_adam_does() {
        let mut burns = AdamConfig::new()
            .with_beta_1(0.9)
            .with_beta_2(0.99)
            .with_weight_decay(Some(WeightDecayConfig::new(0.05)))
            .init();
        let want = trained(|layers, grads| burns.step(1e-2, layers, grads), 4);
        let mut ours = Adam::new(0.9, 0.99, 0.05);
        let got = trained(|layers, grads| ours.step(1e-2, layers, grads), 4);
        let start = trained(|layers, _| layers, 0);
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
