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

use crate::channels_last;
use crate::config::QNetConfig;
use crate::equivariant;
use crate::error::QNetError;
use crate::geometry::Geometry;
use crate::host_copy::copied_to;
use crate::input::NetInput;
use crate::net::PrimitiveNet;
use crate::plane_sums;
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

    /// These nets with every convolution weight held channels-last in memory (its shape and
    /// values unchanged), as a GPU convolves it: a weight laid out as burn lays it out is
    /// copied before each convolution on a GPU. Each weight still requires a gradient where
    /// it did.
    pub fn with_weights_channels_last(self) -> Self {
        channels_last::with_weights_channels_last(self)
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
        let values = plane_sums::weighted_plane_sums(low, weights);
        if heads == 1 {
            // No slice: its backward fills a zero gradient and assigns into it (two kernels
            // on a GPU) for what is the whole tensor.
            return Ok((values.reshape([n]), None));
        }
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
mod tests;
