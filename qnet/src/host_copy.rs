//! A module's copy on another device, its tensors read in one transfer.
//!
//! burn reads a module's record one tensor at a time, and on a GPU each read is a round trip:
//! the host submits, waits for the device to finish and maps the result. The nets hold
//! dozens of tensors and the learner publishes them after every update, so they are read
//! in one burn `Transaction` instead: one wait. A convolution weight that nets on a GPU hold
//! channels-last is read so, as it lies: read as burn lays it out, each would first be
//! copied on the device.

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::prelude::*;
use burn::tensor::{TensorData, Transaction};

use crate::weight_layout::{FROM_CHANNELS_LAST, TO_CHANNELS_LAST, axes, held_channels_last};

/// `module` with its float tensors (all the nets hold) on `device`, each in the form its
/// record saves, read from wherever they are in one transaction. The copy is for reading
/// (a record, bytes): it keeps no gradients.
pub(crate) fn copied_to<M: Module>(module: &M, device: &Device) -> M {
    let mut reads = Reads::default();
    module.visit(&mut reads);
    let data = reads.0.execute().into_iter();
    // Mapped from `valid()`, not a clone: a clone shares its batch norms' running statistics
    // with `module`, and mapping them would move `module`'s own.
    module.valid().map(&mut Placed {
        data,
        device: device.clone(),
    })
}

/// Registers every float tensor of a module, in visiting order.
#[derive(Default)]
struct Reads(Transaction);

impl ModuleVisitor for Reads {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let saved = param.transform_for_save().val();
        let saved = if held_channels_last(&saved.dims()) {
            saved.permute(axes(TO_CHANNELS_LAST))
        } else {
            saved
        };
        self.0 = std::mem::take(&mut self.0).register(saved);
    }
}

/// Puts each float tensor's data, in the same visiting order, on `device`.
struct Placed<I> {
    data: I,
    device: Device,
}

impl<I: Iterator<Item = TensorData>> ModuleMapper for Placed<I> {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let data = self.data.next().expect("one read for every float tensor");
        let tensor = Tensor::from_data(data, &self.device);
        let tensor = if held_channels_last(&param.dims()) {
            tensor.permute(axes(FROM_CHANNELS_LAST))
        } else {
            tensor
        };
        Param::initialized(param.id, tensor)
    }
}
