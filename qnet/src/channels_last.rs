//! Convolution weights kept channels-last on a GPU, for nets that act.
//!
//! burn-cubecl convolves with its weights laid out `[out, kh, kw, in]` and copies a weight
//! kept as burn keeps it, `[out, in, kh, kw]`, before every call: with the stage nets, 24
//! of the 94 kernels of a decision (both nets, 16 rotations; counted on lavapipe). The
//! nets an actor acts with do not change between loads of their weights, so each weight of
//! a kernel wider than one pixel is copied once, there: the same tensor, of the same shape,
//! its memory channels-last, which the convolution then reads as it lies. A
//! rotation-equivariant net is first laid out in full, once, instead of building its full
//! kernels from its base ones before every convolution (608 kernels a decision of the
//! equivariant stage nets).

use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;

use crate::net::PrimitiveNet;

/// `net` (in inference form) as it acts on a GPU: laid out in full (an equivariant net as
/// an ordinary one computing the same maps), its weights channels-last.
pub(crate) fn for_acting(net: &PrimitiveNet) -> PrimitiveNet {
    with_weights_channels_last(net.expanded())
}

/// `nets` with every convolution weight of a kernel wider than one pixel held
/// channels-last (a 1x1 kernel's is channels-last already); the rest as it is. A weight
/// comes out without gradient.
fn with_weights_channels_last<M: Module>(nets: M) -> M {
    nets.map(&mut ChannelsLast)
}

struct ChannelsLast;

impl ModuleMapper for ChannelsLast {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let dims = param.dims();
        if D != 4 || dims[2] * dims[3] == 1 {
            return param;
        }
        let [to, back] = [[0, 2, 3, 1], [0, 3, 1, 2]].map(|axes: [usize; 4]| {
            let mut all = [0; D];
            all.copy_from_slice(&axes);
            all
        });
        // Flattened and shaped back: a permuted view is laid out anew only when made
        // contiguous, which a reshape of it does.
        let channels_last = param.val().permute(to);
        let shape = channels_last.dims();
        let flat: Tensor<1> = channels_last.reshape([dims.iter().product::<usize>()]);
        Param::initialized(param.id, flat.reshape(shape).permute(back))
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
