//! The two nets together: what the actor asks (Q maps for every rotation) and what the
//! learner trains (Q maps for chosen rotations, differentiable), and the weights as bytes.

use burn::module::Module;
use burn::prelude::*;
use burn::store::ModuleRecord;
use burn::tensor::module::interpolate;
use burn::tensor::ops::{
    GridSampleOptions, GridSamplePaddingMode, InterpolateMode, InterpolateOptions,
};
use burn::tensor::{Bytes, TensorData, Transaction};
use sim::Primitive;

use policy::QMaps;

use crate::config::QNetConfig;
use crate::equivariant;
use crate::error::QNetError;
use crate::geometry::Geometry;
use crate::host_copy::copied_to;
use crate::input::NetInput;
use crate::net::PrimitiveNet;
use crate::rotations::{RotatedQMaps, every_rotation, q_maps, try_map};

/// The push and the grasp Q-networks.
#[derive(Module, Debug)]
pub struct QNets {
    pub push: PrimitiveNet,
    pub grasp: PrimitiveNet,
}

impl QNets {
    /// Freshly initialised nets.
    pub fn new(config: &QNetConfig, device: &Device) -> Self {
        Self {
            push: PrimitiveNet::new(config, false, device),
            grasp: PrimitiveNet::new(config, config.grasp_outcome_head, device),
        }
    }

    /// Both nets with their heads started afresh and their trunks kept (pretrained on
    /// another task).
    pub fn with_fresh_heads(mut self, config: &QNetConfig) -> Self {
        let device = self.device();
        self.push.fresh_head(config, &device);
        self.grasp.fresh_head(config, &device);
        self
    }

    /// The device the nets' tensors live on.
    pub fn device(&self) -> Device {
        self.devices()
            .first()
            .cloned()
            .expect("the nets hold tensors on a device")
    }

    pub fn net(&self, primitive: Primitive) -> &PrimitiveNet {
        match primitive {
            Primitive::Push => &self.push,
            Primitive::Grasp => &self.grasp,
        }
    }

    /// Q maps `[n, side, side]` of one primitive, one per (input, rotation) item, on this
    /// module's device (differentiable when that is an autodiff device).
    pub fn q_maps(
        &self,
        primitive: Primitive,
        items: &[(&NetInput, u8)],
        geometry: &Geometry,
    ) -> Result<Tensor<3>, QNetError> {
        let maps = self.maps(primitive, items, geometry, false)?;
        let [n, _, side, _] = maps.dims();
        Ok(maps.reshape([n, side, side]))
    }

    /// [`Self::q_maps`] and, when the primitive's net has an outcome head, its logit maps
    /// `[n, side, side]` from the same forward pass.
    pub fn q_and_outcome_maps(
        &self,
        primitive: Primitive,
        items: &[(&NetInput, u8)],
        geometry: &Geometry,
    ) -> Result<(Tensor<3>, Option<Tensor<3>>), QNetError> {
        let maps = self.maps(primitive, items, geometry, true)?;
        let [n, channels, side, _] = maps.dims();
        let channel = |c: usize| {
            maps.clone()
                .slice([0..n, c..c + 1])
                .reshape([n, side, side])
        };
        Ok((channel(0), (channels == 2).then(|| channel(1))))
    }

    /// The Q value (and with an outcome head the outcome logit) of each item at its own
    /// heightmap pixel: what [`Self::q_and_outcome_maps`] gives there, read off the
    /// low-resolution maps with the rotation back and the upsampling folded into at most
    /// 16 weights per item, so the learner neither forms nor differentiates the full maps.
    pub fn at_pixels(
        &self,
        primitive: Primitive,
        items: &[(&NetInput, u8)],
        pixels: &[(usize, usize)],
        geometry: &Geometry,
    ) -> Result<(Tensor<1>, Option<Tensor<1>>), QNetError> {
        assert_eq!(items.len(), pixels.len(), "one pixel per item");
        let side = geometry.side();
        if let Some(&(row, col)) = pixels.iter().find(|&&(r, c)| r >= side || c >= side) {
            return Err(QNetError::Pixel { row, col, side });
        }
        let (low, turns) = self.low_maps(primitive, items, geometry, true)?;
        let [n, heads, s, _] = low.dims();
        let mut weights = vec![0.0; n * s * s];
        for ((item, &turn), &pixel) in weights.chunks_exact_mut(s * s).zip(&turns).zip(pixels) {
            geometry.add_pixel_weights(turn, pixel, item);
        }
        let weights = Tensor::<4>::from_data(TensorData::new(weights, [n, 1, s, s]), &low.device());
        let values = (low * weights).sum_dim(3).sum_dim(2);
        if heads == 1 {
            // No slice: its backward fills a zero gradient and assigns into it (two kernels
            // on a GPU) for what is the whole tensor.
            return Ok((values.reshape([n]), None));
        }
        let values = values.reshape([n, heads]);
        let head = |h: usize| values.clone().slice([0..n, h..h + 1]).reshape([n]);
        Ok((head(0), Some(head(1))))
    }

    /// The maps `[n, channels, side, side]` of one primitive's items: the Q value's, then
    /// with `outcome` the outcome logit's when the net has that head.
    fn maps(
        &self,
        primitive: Primitive,
        items: &[(&NetInput, u8)],
        geometry: &Geometry,
        outcome: bool,
    ) -> Result<Tensor<4>, QNetError> {
        let (low, turns) = self.low_maps(primitive, items, geometry, outcome)?;
        let [n, heads, s, _] = low.dims();
        let grid = Tensor::<4>::from_data(
            TensorData::new(geometry.back_grid(&turns), [n, s, s, 2]),
            &low.device(),
        );
        let back = low.grid_sample_2d(
            grid,
            GridSampleOptions::new(InterpolateMode::Bilinear)
                .with_padding_mode(GridSamplePaddingMode::Border)
                .with_align_corners(false),
        );
        let p = geometry.padded();
        let full = interpolate(
            back,
            InterpolateOptions::new(InterpolateMode::Bilinear)
                .with_align_corners(false)
                .with_output_size([p, p]),
        );
        let (o, side) = (geometry.offset(), geometry.side());
        Ok(full.slice([0..n, 0..heads, o..o + side, o..o + side]))
    }

    /// The low-resolution maps `[n, channels, s, s]` of one primitive's items, each still
    /// in its input rotation's frame, and that rotation per item (what rotates it back).
    /// Items that differ only by quarter turns of the action share one pass of an
    /// equivariant net.
    fn low_maps(
        &self,
        primitive: Primitive,
        items: &[(&NetInput, u8)],
        geometry: &Geometry,
        outcome: bool,
    ) -> Result<(Tensor<4>, Vec<u8>), QNetError> {
        let device = self.device();
        let net = self.net(primitive);
        let angles = net.angles_per_pass();
        let s = geometry.low_side();
        // The passes (input, input rotation) and each item's (pass, output channel).
        let mut passes: Vec<(&NetInput, u8)> = Vec::new();
        let mut picks = Vec::with_capacity(items.len());
        for &(input, rotation) in items {
            geometry.check(input, rotation)?;
            let (turn, channel) = equivariant::pass_and_channel(rotation, angles);
            let same = |&(other, t): &(&NetInput, u8)| std::ptr::eq(other, input) && t == turn;
            let pass = passes.iter().position(same).unwrap_or_else(|| {
                passes.push((input, turn));
                passes.len() - 1
            });
            picks.push((pass, channel));
        }
        let m = passes.len();
        let [colour, depth, mask] = geometry.rotated_planes(&passes, &device);
        let low = if outcome {
            net.forward_with_outcome(colour, depth, mask)
        } else {
            net.forward(colour, depth, mask)
        };
        // Each item's channel of each head (Q, then outcome).
        let channels = low.dims()[1];
        let heads = channels / angles;
        let rows: Vec<i64> = picks
            .iter()
            .flat_map(|&(pass, channel)| {
                (0..heads).map(move |head| (pass * channels + head * angles + channel) as i64)
            })
            .collect();
        let n = items.len();
        // Every pass's every channel in order (an ordinary net's batch, or an equivariant
        // pass asked for its quarter turns in order) needs no selection, nor its scatter
        // back in the backward: only its channels regrouped per item.
        let low = low.reshape([m * channels, s, s]);
        let low = if rows.iter().copied().eq(0..(m * channels) as i64) {
            low
        } else {
            low.select(0, Tensor::<1, Int>::from_ints(rows.as_slice(), &device))
        };
        let low = low.reshape([n, heads, s, s]);
        let turns = picks.iter().map(|&(pass, _)| passes[pass].1).collect();
        Ok((low, turns))
    }

    /// The weights of both nets as bytes (burn's burnpack format), for checkpoints and for
    /// broadcasting to actors. Nets on a GPU are first read to the CPU in one transfer.
    pub fn to_bytes(&self) -> Result<Vec<u8>, QNetError> {
        let host = Device::flex();
        let nets = if self.device().without_autodiff() == host {
            self.clone()
        } else {
            copied_to(self, &host)
        };
        let bytes = nets
            .into_record()
            .into_bytes()
            .map_err(|e| QNetError::Weights(e.to_string()))?;
        Ok(bytes.to_vec())
    }

    /// These nets with the weights from `bytes` (made by [`QNets::to_bytes`] for nets of the
    /// same configuration).
    pub fn load_bytes(self, bytes: &[u8]) -> Result<Self, QNetError> {
        let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(bytes.to_vec()))
            .map_err(|e| QNetError::Weights(e.to_string()))?;
        self.try_load_record(record).map_err(|e| {
            let why = e.to_string();
            // Nets saved before the convolutions ahead of a batch norm lost their biases.
            let hint = if why.contains("conv.bias") {
                " (saved by an older pushgrasp, whose convolutions before a batch norm had \
                 biases; these nets have none: train them again)"
            } else {
                ""
            };
            QNetError::Weights(format!("{why}{hint}"))
        })
    }
}

/// One forward pass of each net over every rotation of every input, and their maps read back
/// together once every pass is queued (on a GPU one wait, not one a net, and the first net's
/// pass runs while the host issues the next's).
impl RotatedQMaps for QNets {
    fn all_rotations_of_each<const N: usize>(
        &self,
        primitives: [Primitive; N],
        inputs: &[&NetInput],
        geometry: &Geometry,
    ) -> Result<Vec<[QMaps; N]>, QNetError> {
        let rotations = every_rotation();
        let items: Vec<(&NetInput, u8)> = inputs
            .iter()
            .flat_map(|&input| rotations.iter().map(move |&k| (input, k)))
            .collect();
        let per_input = rotations.len() * geometry.side() * geometry.side();
        let passes = try_map(primitives, |primitive| {
            self.q_maps(primitive, &items, geometry)
        })?;
        let read: [TensorData; N] = passes
            .into_iter()
            .fold(Transaction::default(), Transaction::register)
            .execute()
            .try_into()
            .expect("one read a net");
        let mut maps = try_map(read, |data| {
            let values = data.try_into_vec::<f32>().expect("Q maps are f32");
            Ok(values
                .chunks_exact(per_input)
                .map(|one| q_maps(geometry, one.to_vec()))
                .collect::<Result<Vec<_>, _>>()?
                .into_iter())
        })?;
        Ok((0..inputs.len())
            .map(|_| {
                maps.each_mut()
                    .map(|m| m.next().expect("maps for every input"))
            })
            .collect())
    }

    fn rotations(
        &self,
        primitive: Primitive,
        input: &NetInput,
        rotations: &[u8],
        geometry: &Geometry,
    ) -> Result<Vec<f32>, QNetError> {
        let items: Vec<(&NetInput, u8)> = rotations.iter().map(|&k| (input, k)).collect();
        let maps = self.q_maps(primitive, &items, geometry)?;
        Ok(maps
            .into_data()
            .try_to_vec::<f32>()
            .expect("Q maps are f32"))
    }
}

#[cfg(test)]
mod tests {
    use burn::module::Param;
    use burn::tensor::Distribution;

    use super::*;
    use crate::testing::{assert_close, patterned_input};

    #[test]
    fn values_at_pixels_and_their_gradients_are_the_full_maps_at_those_pixels() {
        let side = 24;
        let input = patterned_input(side);
        // The corners and edges (the upsampling and the rotation back clamp there) and
        // rotations in every quadrant.
        let rotations = [0u8, 3, 5, 8, 13, 15];
        let pixels = [(0, 0), (23, 23), (5, 17), (12, 0), (23, 6), (11, 11)];
        let items: Vec<(&NetInput, u8)> = rotations.iter().map(|&k| (&input, k)).collect();
        for rotation_equivariant in [false, true] {
            let config = QNetConfig {
                trunk_widths: vec![4, 8],
                head_width: 8,
                grasp_outcome_head: true,
                rotation_equivariant,
                ..QNetConfig::default()
            };
            let device = Device::flex().autodiff();
            let nets = QNets::new(&config, &device).train();
            let geometry = Geometry::new(side, &config);
            let what = |part: &str| format!("equivariant {rotation_equivariant}: {part}");
            let coefficients = |offset| {
                Tensor::<1>::random([items.len()], Distribution::Default, &device)
                    .add_scalar(offset)
            };
            let (a, b) = (coefficients(0.5), coefficients(1.0));
            // What the learner differentiated before: the full maps masked at the pixels.
            let (maps, logits) = nets
                .q_and_outcome_maps(Primitive::Grasp, &items, &geometry)
                .unwrap();
            let mut one_hot = vec![0.0; items.len() * side * side];
            for (j, &(row, col)) in pixels.iter().enumerate() {
                one_hot[(j * side + row) * side + col] = 1.0;
            }
            let one_hot = Tensor::<3>::from_data(
                TensorData::new(one_hot, [items.len(), side, side]),
                &device,
            );
            let pick = |maps: Tensor<3>| {
                (maps * one_hot.clone())
                    .sum_dim(2)
                    .sum_dim(1)
                    .flatten::<1>(0, 2)
            };
            let full = (pick(maps), pick(logits.unwrap()));
            let direct = nets
                .at_pixels(Primitive::Grasp, &items, &pixels, &geometry)
                .unwrap();
            let direct = (direct.0, direct.1.unwrap());
            let values = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap();
            assert_close(
                &values(direct.0.clone()),
                &values(full.0.clone()),
                1e-5,
                &what("Q"),
            );
            assert_close(
                &values(direct.1.clone()),
                &values(full.1.clone()),
                1e-5,
                &what("logit"),
            );
            let loss =
                |(q, logit): (Tensor<1>, Tensor<1>)| (q * a.clone() + logit * b.clone()).sum();
            let (direct, full) = (loss(direct).backward(), loss(full).backward());
            let net = &nets.grasp;
            let outcome = net.outcome_out.as_ref().unwrap();
            for (part, weight) in [
                (
                    "the trunk's first convolution",
                    &net.colour.blocks[0].conv.weight,
                ),
                ("the Q output", &net.head_out.weight),
                ("the outcome output", &outcome.weight),
            ] {
                let grad = |grads| values(weight.val().grad(grads).unwrap().flatten::<1>(0, 3));
                assert_close(&grad(&direct), &grad(&full), 1e-4, &what(part));
            }
        }
    }

    #[test]
    fn an_equivariant_pass_asked_for_all_its_channels_in_order_gives_one_map_per_item() {
        let side = 16;
        let input = patterned_input(side);
        let config = QNetConfig {
            trunk_widths: vec![4, 8],
            head_width: 8,
            rotation_equivariant: true,
            ..QNetConfig::default()
        };
        let nets = QNets::new(&config, &Device::flex());
        let geometry = Geometry::new(side, &config);
        // Rotations a quarter turn apart: one pass, its four channels in order.
        let together = nets
            .rotations(Primitive::Grasp, &input, &[0, 4, 8, 12], &geometry)
            .unwrap();
        let apart: Vec<f32> = [0u8, 4, 8, 12]
            .iter()
            .flat_map(|&k| {
                nets.rotations(Primitive::Grasp, &input, &[k], &geometry)
                    .unwrap()
            })
            .collect();
        assert_eq!(together.len(), 4 * side * side);
        assert_close(&together, &apart, 1e-5, "four channels of one pass");
    }

    #[test]
    fn every_rotation_of_several_inputs_in_one_pass_gives_each_inputs_own_maps() {
        let side = 16;
        let (a, b) = (patterned_input(side), patterned_input(side).mirrored());
        let config = QNetConfig {
            trunk_widths: vec![4, 8],
            head_width: 8,
            ..QNetConfig::default()
        };
        let nets = QNets::new(&config, &Device::flex());
        let geometry = Geometry::new(side, &config);
        let primitives = [Primitive::Push, Primitive::Grasp];
        let together = nets
            .all_rotations_of_each(primitives, &[&a, &b], &geometry)
            .unwrap();
        assert_eq!(together.len(), 2);
        for (maps, input) in together.iter().zip([&a, &b]) {
            for (maps, primitive) in maps.iter().zip(primitives) {
                let alone = nets.all_rotations(primitive, input, &geometry).unwrap();
                assert_close(maps.values(), alone.values(), 1e-5, "one input's maps");
            }
        }
        assert_ne!(together[0][1].values(), together[1][1].values());
    }

    #[test]
    fn nets_copied_in_one_read_save_the_bytes_they_were_read_from() {
        let device = Device::flex();
        let config = QNetConfig {
            context_dilations: vec![1, 2],
            grasp_outcome_head: true,
            ..QNetConfig::default()
        };
        let nets = QNets::new(&config, &device);
        // As a trainer holds them: on the autodiff device, in training form.
        let trained = nets.clone().to_device(&device.clone().autodiff()).train();
        let copy = copied_to(&trained, &device);
        assert!(!copy.device().is_autodiff());
        assert_eq!(copy.to_bytes().unwrap(), nets.to_bytes().unwrap());
        // The nets copied from are left as they were, batch norms' running statistics too
        // (which a module's clones share).
        let mut left = AllAutodiff(true);
        trained.visit(&mut left);
        assert!(left.0, "a tensor of the nets copied from moved");
    }

    /// Whether every float tensor of a module is on an autodiff device.
    struct AllAutodiff(bool);

    impl burn::module::ModuleVisitor for AllAutodiff {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0 &= param.val().device().is_autodiff();
        }
    }

    #[test]
    fn weights_with_biases_before_a_batch_norm_are_refused_saying_why() {
        let (config, device) = (QNetConfig::default(), Device::flex());
        let mut older = QNets::new(&config, &device);
        // What an older pushgrasp saved: its blocks' convolutions had biases.
        let conv = &mut older.grasp.colour.blocks[0].conv;
        let channels = conv.weight.dims()[0];
        conv.bias = Some(Param::from_tensor(Tensor::<1>::zeros([channels], &device)));
        let bytes = older.to_bytes().unwrap();
        let err = QNets::new(&config, &device)
            .load_bytes(&bytes)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("grasp.colour.blocks.0.conv.bias") && err.contains("older pushgrasp"),
            "{err}"
        );
    }
}
