//! Polyak averaging of the nets: the weights the learner publishes and checkpoints can be a
//! running average of the trained ones instead of the trained ones themselves.
//!
//! Why: actors act with the published nets and bootstrap their labels on them, and a Q map's
//! maximum over thousands of pixels picks out whatever noise the last few updates left in
//! the trained net. An average over the last 1 / rate updates keeps what they agree on.

use std::collections::HashMap;

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::prelude::*;
use qnet::QNets;

/// `average` moved `rate` of the way towards `trained`, parameter by parameter (batch norm
/// running statistics included). Both must be copies of one module (the same parameter ids)
/// on one device; `trained` is read in its inference form.
pub fn polyak_step(average: QNets, trained: &QNets, rate: f32) -> QNets {
    let mut collect = Collect::default();
    trained.visit(&mut collect);
    average.map(&mut Blend {
        trained: collect.params,
        rate,
    })
}

/// Every float parameter of a module, flattened, by id.
#[derive(Default)]
struct Collect {
    params: HashMap<ParamId, Tensor<1>>,
}

impl ModuleVisitor for Collect {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.params.insert(param.id, param.val().flatten(0, D - 1));
    }
}

/// Blends each parameter with the collected one of the same id.
struct Blend {
    trained: HashMap<ParamId, Tensor<1>>,
    rate: f32,
}

impl ModuleMapper for Blend {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let trained = self
            .trained
            .remove(&param.id)
            .expect("the averaged nets are a copy of the trained ones");
        let rate = self.rate;
        param.map(|average| {
            let trained = trained.reshape(average.shape());
            average.clone() + (trained - average) * rate
        })
    }
}
