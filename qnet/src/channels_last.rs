//! Convolution weights kept channels-last on a GPU, for nets that act and nets that train.
//!
//! burn-cubecl convolves with its weights laid out `[out, kh, kw, in]` and copies a weight
//! kept as burn keeps it, `[out, in, kh, kw]`, before every call: with the stage nets, 24
//! of the 94 kernels of a decision (both nets, 16 rotations; counted on lavapipe). The
//! nets an actor acts with do not change between loads of their weights, so each weight is
//! copied once, there: the same tensor, of the same shape, its memory channels-last, which
//! the convolution then reads as it lies (a 1x1 kernel's memory is in that order already,
//! but its strides, set anew, are what a read and an input's gradient check). A
//! rotation-equivariant net is first laid out in full, once, instead of building its full
//! kernels from its base ones before every convolution (608 kernels a decision of the
//! equivariant stage nets). Nets that train on a GPU are laid out so once too: their Adam
//! writes each parameter laid out as it lies, so a weight stays channels-last from update
//! to update, and is read so when the nets are published.

use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;

use crate::net::PrimitiveNet;
use crate::weight_layout::{FROM_CHANNELS_LAST, TO_CHANNELS_LAST, axes, held_channels_last};

/// `net` (in inference form) as it acts on a GPU: laid out in full (an equivariant net as
/// an ordinary one computing the same maps), its weights channels-last.
pub(crate) fn for_acting(net: &PrimitiveNet) -> PrimitiveNet {
    with_weights_channels_last(net.expanded())
}

/// `nets` with every convolution weight held channels-last; the rest as it is. Each weight
/// comes out a leaf, requiring a gradient where it did.
pub(crate) fn with_weights_channels_last<M: Module>(nets: M) -> M {
    nets.map(&mut ChannelsLast)
}

struct ChannelsLast;

impl ModuleMapper for ChannelsLast {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let dims = param.dims();
        if !held_channels_last(&dims) {
            return param;
        }
        let [to, back] = [TO_CHANNELS_LAST, FROM_CHANNELS_LAST].map(axes::<D>);
        // Flattened and shaped back: a permuted view is laid out anew only when made
        // contiguous, which a reshape of it does.
        let require_grad = param.is_require_grad();
        let channels_last = param.val().permute(to);
        let shape = channels_last.dims();
        let flat: Tensor<1> = channels_last.reshape([dims.iter().product::<usize>()]);
        // A leaf again, not the result of the operations that laid it out.
        let laid_out = flat.reshape(shape).permute(back).detach();
        Param::initialized(param.id, laid_out).set_require_grad(require_grad)
    }
}

#[cfg(test)]
mod tests {
    use burn::tensor::Distribution;
    use sim::Primitive;

    use super::*;
    use crate::geometry::Geometry;
    use crate::testing::{assert_close, patterned_input};
    use crate::{QNetConfig, QNets, RotatedQMaps};

    /// Every float tensor of a module's values and shape, in visiting order.
    #[derive(Default)]
    struct Values(Vec<(Vec<usize>, Vec<f32>)>);

    impl burn::module::ModuleVisitor for Values {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let tensor = param.val();
            let values = tensor.clone().into_data().try_to_vec::<f32>().unwrap();
            self.0.push((tensor.dims().to_vec(), values));
        }
    }

    fn values(nets: &QNets) -> Vec<(Vec<usize>, Vec<f32>)> {
        let mut values = Values::default();
        nets.visit(&mut values);
        values.0
    }

    #[test]
    fn weights_laid_out_channels_last_keep_their_shapes_and_values() {
        let config = QNetConfig {
            context_dilations: vec![1, 2],
            ..QNetConfig::default()
        };
        let nets = QNets::new(&config, &Device::flex());
        let before = values(&nets);
        assert!(
            before
                .iter()
                .any(|(dims, _)| dims.len() == 4 && dims[2] == 3)
        );
        assert_eq!(values(&with_weights_channels_last(nets)), before);
    }

    /// Whether each float tensor of a module requires a gradient, in visiting order.
    #[derive(Default)]
    struct Tracked(Vec<bool>);

    impl burn::module::ModuleVisitor for Tracked {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.push(param.is_require_grad());
        }
    }

    #[test]
    fn weights_laid_out_channels_last_still_learn() {
        let device = Device::flex().autodiff();
        let nets = QNets::new(&QNetConfig::default(), &device);
        let (mut before, mut after) = (Tracked::default(), Tracked::default());
        nets.visit(&mut before);
        let laid_out = with_weights_channels_last(nets);
        laid_out.visit(&mut after);
        assert!(before.0.iter().any(|&tracked| tracked));
        assert_eq!(after.0, before.0);
        // A leaf each: a backward pass reaches every weight of the net it runs through.
        let planes = |channels| Tensor::<4>::ones([1, channels, 8, 8], &device);
        let q = laid_out.grasp.forward(planes(3), planes(1), planes(1));
        let grads = q.sum().backward();
        let mut missing = 0;
        laid_out.grasp.visit(&mut Reached {
            grads: &grads,
            missing: &mut missing,
        });
        assert_eq!(missing, 0, "{missing} weights got no gradient");
    }

    /// Counts the 4-D weights a backward pass gave no gradient.
    struct Reached<'a> {
        grads: &'a burn::tensor::Gradients,
        missing: &'a mut usize,
    }

    impl burn::module::ModuleVisitor for Reached<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if D == 4 && param.val().grad(self.grads).is_none() {
                *self.missing += 1;
            }
        }
    }

    #[test]
    fn nets_laid_out_to_act_give_their_own_maps_an_equivariant_nets_included() {
        let side = 16;
        let input = patterned_input(side);
        for rotation_equivariant in [false, true] {
            let config = QNetConfig {
                trunk_widths: vec![4, 8],
                context_dilations: vec![1],
                head_width: 8,
                rotation_equivariant,
                ..QNetConfig::default()
            };
            let geometry = Geometry::new(side, &config);
            // A forward pass in training first, so the batch norms' running statistics
            // (which an equivariant net shares within a field) are not their initial ones.
            let device = Device::flex().autodiff();
            let trained = QNets::new(&config, &device);
            let p = geometry.padded();
            let planes =
                |channels| Tensor::<4>::random([2, channels, p, p], Distribution::Default, &device);
            for net in [&trained.push, &trained.grasp] {
                net.forward(planes(3), planes(1), planes(1));
            }
            let nets = trained.valid();
            let acting = QNets {
                push: for_acting(&nets.push),
                grasp: for_acting(&nets.grasp),
            };
            assert_eq!(acting.grasp.group(), 1);
            let primitives = [Primitive::Push, Primitive::Grasp];
            let [ours] = acting
                .all_rotations_of_each(primitives, &[&input], &geometry)
                .unwrap()
                .try_into()
                .unwrap();
            for (maps, primitive) in ours.iter().zip(primitives) {
                let theirs = nets.all_rotations(primitive, &input, &geometry).unwrap();
                let what = format!("equivariant {rotation_equivariant}: {primitive:?}");
                assert_close(maps.values(), theirs.values(), 1e-5, &what);
            }
        }
    }
}
