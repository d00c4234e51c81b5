//! The two nets together: what the actor asks (Q maps for every rotation) and what the
//! learner trains (Q maps for chosen rotations, differentiable), and the weights as bytes.

use burn::module::Module;
use burn::prelude::*;
use burn::store::ModuleRecord;
use burn::tensor::Bytes;
use burn::tensor::module::interpolate;
use burn::tensor::ops::{
    GridSampleOptions, GridSamplePaddingMode, InterpolateMode, InterpolateOptions,
};
use sim::Primitive;

use policy::QMaps;

use crate::acting::every_rotation;
use crate::config::QNetConfig;
use crate::equivariant;
use crate::error::QNetError;
use crate::geometry::Geometry;
use crate::input::NetInput;
use crate::net::PrimitiveNet;

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

    /// The maps `[n, channels, side, side]` of one primitive's items: the Q value's, then
    /// with `outcome` the outcome logit's when the net has that head. Items that differ only
    /// by quarter turns of the action share one pass of an equivariant net.
    fn maps(
        &self,
        primitive: Primitive,
        items: &[(&NetInput, u8)],
        geometry: &Geometry,
        outcome: bool,
    ) -> Result<Tensor<4>, QNetError> {
        let device = self.device();
        let net = self.net(primitive);
        let (p, s, side) = (geometry.padded(), geometry.low_side(), geometry.side());
        // The passes (input, input rotation) and each item's (pass, output channel).
        let mut passes: Vec<(&NetInput, u8)> = Vec::new();
        let mut picks = Vec::with_capacity(items.len());
        for &(input, rotation) in items {
            geometry.check(input, rotation)?;
            let (turn, channel) = equivariant::pass_and_channel(rotation, net.group());
            let same = |&(other, t): &(&NetInput, u8)| std::ptr::eq(other, input) && t == turn;
            let pass = passes.iter().position(same).unwrap_or_else(|| {
                passes.push((input, turn));
                passes.len() - 1
            });
            picks.push((pass, channel));
        }
        let [mut colour, mut depth, mut mask] = [Vec::new(), Vec::new(), Vec::new()];
        for &(input, turn) in &passes {
            geometry.rotate_input(input, turn, [&mut colour, &mut depth, &mut mask]);
        }
        let m = passes.len();
        let plane = |values: Vec<f32>, channels: usize| {
            Tensor::<4>::from_data(TensorData::new(values, [m, channels, p, p]), &device)
        };
        let planes = (plane(colour, 3), plane(depth, 1), plane(mask, 1));
        let low = if outcome {
            net.forward_with_outcome(planes.0, planes.1, planes.2)
        } else {
            net.forward(planes.0, planes.1, planes.2)
        };
        // Each item's channel of each head (Q, then outcome), rotated back by its pass's
        // input rotation.
        let channels = low.dims()[1];
        let heads = channels / net.group();
        let rows: Vec<i64> = picks
            .iter()
            .flat_map(|&(pass, channel)| {
                (0..heads).map(move |head| (pass * channels + head * net.group() + channel) as i64)
            })
            .collect();
        let n = items.len();
        let low = low
            .reshape([m * channels, s, s])
            .select(0, Tensor::<1, Int>::from_ints(rows.as_slice(), &device))
            .reshape([n, heads, s, s]);
        let turns: Vec<u8> = picks.iter().map(|&(pass, _)| passes[pass].1).collect();
        let grid = Tensor::<4>::from_data(
            TensorData::new(geometry.back_grid(&turns), [n, s, s, 2]),
            &device,
        );
        let back = low.grid_sample_2d(
            grid,
            GridSampleOptions::new(InterpolateMode::Bilinear)
                .with_padding_mode(GridSamplePaddingMode::Border)
                .with_align_corners(false),
        );
        let full = interpolate(
            back,
            InterpolateOptions::new(InterpolateMode::Bilinear)
                .with_align_corners(false)
                .with_output_size([p, p]),
        );
        let o = geometry.offset();
        Ok(full.slice([0..n, 0..heads, o..o + side, o..o + side]))
    }

    /// Q maps of one primitive for all rotations, as the actor's plain arrays.
    pub fn all_rotations(
        &self,
        primitive: Primitive,
        input: &NetInput,
        geometry: &Geometry,
    ) -> Result<QMaps, QNetError> {
        every_rotation(geometry, |rotations| {
            self.rotations(primitive, input, rotations, geometry)
        })
    }

    /// The Q maps of one primitive at `rotations`, one `side x side` map after another.
    pub fn rotations(
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

    /// The weights of both nets as bytes (burn's burnpack format), for checkpoints and for
    /// broadcasting to actors.
    pub fn to_bytes(&self) -> Result<Vec<u8>, QNetError> {
        let bytes = self
            .clone()
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

#[cfg(test)]
mod tests {
    use burn::module::Param;

    use super::*;

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
