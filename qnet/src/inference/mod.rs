//! The nets' inference form on the CPU: what an actor runs for every decision.
//!
//! The same function as [`PrimitiveNet::forward`] in inference (batch norms on their running
//! statistics), computed the way an inference engine does: each batch norm folded into the
//! convolution before it, each convolution one matrix product over its unfolded input with
//! bias and ReLU applied in one pass, every buffer kept between calls, the 16 rotations
//! spread over the cores. The rotations back use [`Geometry`]'s precomputed bilinear taps.
//! burn's CPU backend runs the same nets several times slower at these shapes (small
//! tensors, an allocation and a copy per operation); `pushgrasp bench learner` prints both.
//! The learner keeps training with burn; the agreement tests hold the two to the same Q
//! maps.

mod conv;

use std::cell::RefCell;

use burn::nn::BatchNorm;
use rayon::prelude::*;
use sim::Primitive;

use policy::QMaps;

use crate::equivariant;
use crate::error::QNetError;
use crate::geometry::Geometry;
use crate::input::NetInput;
use crate::net::{PrimitiveNet, Trunk};
use crate::qnets::QNets;
use crate::rotations::{RotatedQMaps, every_rotation, q_maps, try_map};
use conv::{FoldedConv, Scratch, norm_affine};
pub(crate) use conv::{even_padding, values};

/// Both nets in inference form, built from their weights (rebuild after loading new ones).
#[derive(Clone, Debug)]
pub struct Inference {
    push: NetForm,
    grasp: NetForm,
}

/// One primitive's net in inference form.
#[derive(Clone, Debug)]
struct NetForm {
    /// Colour, depth and mask trunks, each convolution with its batch norm and ReLU.
    trunks: [Vec<FoldedConv>; 3],
    /// Context convolutions over the trunks' features together (empty unless fused).
    fused: Vec<FoldedConv>,
    /// The head's first batch norm as a per-channel scale and shift, then ReLU.
    head_in: (Vec<f32>, Vec<f32>),
    /// The head's hidden 1x1 convolution with its batch norm and ReLU.
    hidden: FoldedConv,
    out: FoldedConv,
}

/// One thread's buffers, reused by every forward pass it runs.
#[derive(Default)]
struct Workspace {
    scratch: Scratch,
    /// The rotated input planes.
    planes: [Vec<f32>; 3],
    ping: Vec<f32>,
    pong: Vec<f32>,
    features: Vec<f32>,
    hidden: Vec<f32>,
    low: Vec<f32>,
    back: Vec<f32>,
}

thread_local! {
    static WORKSPACE: RefCell<Workspace> = RefCell::new(Workspace::default());
}

impl Inference {
    /// The inference form of `nets`' current weights.
    pub fn new(nets: &QNets) -> Result<Self, QNetError> {
        Ok(Self {
            push: NetForm::new(&nets.push)?,
            grasp: NetForm::new(&nets.grasp)?,
        })
    }

    fn net(&self, primitive: Primitive) -> &NetForm {
        match primitive {
            Primitive::Push => &self.push,
            Primitive::Grasp => &self.grasp,
        }
    }

    /// [`RotatedQMaps::rotations`] of each of `primitives` for each of `inputs`: every input
    /// rotation they need computed once and run through each of their nets.
    fn rotations_of_each<const N: usize>(
        &self,
        primitives: [Primitive; N],
        inputs: &[&NetInput],
        rotations: &[u8],
        geometry: &Geometry,
    ) -> Result<Vec<[Vec<f32>; N]>, QNetError> {
        for input in inputs {
            for &k in rotations {
                geometry.check(input, k)?;
            }
        }
        let nets = primitives.map(|primitive| self.net(primitive));
        // The input rotations the rotations asked for need, each run once through every net
        // (the two nets share their shape, so they need the same ones): its low-resolution
        // maps, one a quarter turn of the action.
        let turn_and_channel = |net: &NetForm, k| equivariant::pass_and_channel(k, net.group());
        let mut turns: Vec<u8> = nets
            .iter()
            .flat_map(|&net| rotations.iter().map(move |&k| turn_and_channel(net, k).0))
            .collect();
        turns.sort_unstable();
        turns.dedup();
        // `lows[i * turns.len() + t][j]`: net `j`'s low-resolution maps of input `i` at turn
        // `turns[t]`.
        let lows: Vec<[Vec<f32>; N]> = (0..inputs.len() * turns.len())
            .into_par_iter()
            .map(|pass| {
                let (input, turn) = (inputs[pass / turns.len()], turns[pass % turns.len()]);
                WORKSPACE.with_borrow_mut(|ws| {
                    ws.planes.iter_mut().for_each(Vec::clear);
                    let [colour, depth, mask] = &mut ws.planes;
                    geometry.rotate_input(input, turn, [colour, depth, mask]);
                    let planes = std::mem::take(&mut ws.planes);
                    let lows = nets.map(|net| {
                        let mut low = Vec::new();
                        net.forward(&planes, geometry.padded(), ws, &mut low);
                        low
                    });
                    ws.planes = planes;
                    lows
                })
            })
            .collect();
        let area = geometry.side() * geometry.side();
        let low_area = geometry.low_side() * geometry.low_side();
        let mut values: Vec<[Vec<f32>; N]> = (0..inputs.len())
            .map(|_| std::array::from_fn(|_| vec![0.0; rotations.len() * area]))
            .collect();
        values
            .par_iter_mut()
            .enumerate()
            .flat_map(|(i, maps)| {
                maps.par_iter_mut()
                    .enumerate()
                    .map(move |(j, maps)| (i, j, maps))
            })
            .for_each(|(i, j, maps)| {
                maps.par_chunks_mut(area)
                    .zip(rotations)
                    .for_each(|(map, &k)| {
                        let (turn, channel) = turn_and_channel(nets[j], k);
                        let t = turns.binary_search(&turn).expect("every turn was run");
                        let low = &lows[i * turns.len() + t][j];
                        let low = &low[channel * low_area..(channel + 1) * low_area];
                        WORKSPACE.with_borrow_mut(|ws| {
                            rotate_back(low, turn, geometry, &mut ws.back, map)
                        });
                    });
            });
        Ok(values)
    }

    /// The low-resolution Q maps (`n x group x low_side^2`: one a quarter turn of the
    /// action in an equivariant net) of `n` inputs already padded and rotated, laid out as
    /// [`Geometry::rotate_input`] appends them: the convolutions alone, without the
    /// rotations around them.
    pub fn low_maps(
        &self,
        primitive: Primitive,
        rotated: [&[f32]; 3],
        geometry: &Geometry,
    ) -> Vec<f32> {
        let net = self.net(primitive);
        let area = geometry.padded() * geometry.padded();
        let n = rotated[1].len() / area;
        let low_area = net.group() * geometry.low_side() * geometry.low_side();
        let mut maps = vec![0.0; n * low_area];
        maps.par_chunks_mut(low_area)
            .enumerate()
            .for_each(|(i, map)| {
                WORKSPACE.with_borrow_mut(|ws| {
                    let planes = [
                        &rotated[0][3 * i * area..3 * (i + 1) * area],
                        &rotated[1][i * area..(i + 1) * area],
                        &rotated[2][i * area..(i + 1) * area],
                    ];
                    let mut low = std::mem::take(&mut ws.low);
                    net.forward(&planes, geometry.padded(), ws, &mut low);
                    map.copy_from_slice(&low);
                    ws.low = low;
                });
            });
        maps
    }
}

/// Every input rotation of every input is computed once for all the primitives, and the
/// passes share the cores, so that several environments' decisions keep them busy where one
/// alone has fewer passes than cores or ends unevenly.
impl RotatedQMaps for Inference {
    fn all_rotations_of_each<const N: usize>(
        &self,
        primitives: [Primitive; N],
        inputs: &[&NetInput],
        geometry: &Geometry,
    ) -> Result<Vec<[QMaps; N]>, QNetError> {
        self.rotations_of_each(primitives, inputs, &every_rotation(), geometry)?
            .into_iter()
            .map(|values| try_map(values, |values| q_maps(geometry, values)))
            .collect()
    }

    fn rotations(
        &self,
        primitive: Primitive,
        input: &NetInput,
        rotations: &[u8],
        geometry: &Geometry,
    ) -> Result<Vec<f32>, QNetError> {
        let mut values = self.rotations_of_each([primitive], &[input], rotations, geometry)?;
        let [values] = values.pop().expect("one input, one set of maps");
        Ok(values)
    }
}

impl NetForm {
    fn new(net: &PrimitiveNet) -> Result<Self, QNetError> {
        let net = &net.expanded();
        let blocks = |trunk: &Trunk| -> Result<Vec<FoldedConv>, QNetError> {
            trunk
                .blocks
                .iter()
                .map(|block| FoldedConv::new(&block.conv, Some(&block.norm), true))
                .collect()
        };
        Ok(Self {
            trunks: [
                blocks(&net.colour)?,
                blocks(&net.depth)?,
                blocks(&net.mask)?,
            ],
            fused: blocks(&net.fused)?,
            head_in: norm_affine(&net.head_norm_in)?,
            hidden: FoldedConv::new(&net.head_hidden, Some(&net.head_norm_hidden), true)?,
            out: FoldedConv::new(&net.head_out, None::<&BatchNorm>, false)?,
        })
    }

    /// Channels a field: the action angles a quarter turn apart that one pass scores (its
    /// output's maps).
    fn group(&self) -> usize {
        self.out.channels_out()
    }

    /// The low-resolution Q map of one padded, rotated input (colour `[3, P, P]`, depth and
    /// mask `[1, P, P]`) into `low`.
    fn forward<P: AsRef<[f32]>>(
        &self,
        planes: &[P; 3],
        padded: usize,
        ws: &mut Workspace,
        low: &mut Vec<f32>,
    ) {
        let Workspace {
            scratch,
            ping,
            pong,
            features,
            hidden,
            ..
        } = ws;
        features.clear();
        let mut side = padded;
        for (trunk, plane) in self.trunks.iter().zip(planes) {
            side = chain(trunk, plane.as_ref(), padded, ping, pong, scratch);
            features.extend_from_slice(ping);
        }
        let features: &mut Vec<f32> = if self.fused.is_empty() {
            features
        } else {
            side = chain(&self.fused, features, side, ping, pong, scratch);
            ping
        };
        let area = side * side;
        let (scale, shift) = &self.head_in;
        for ((plane, s), t) in features.chunks_exact_mut(area).zip(scale).zip(shift) {
            plane.iter_mut().for_each(|v| *v = (*v * s + t).max(0.0));
        }
        hidden.resize(self.hidden.channels_out() * area, 0.0);
        self.hidden.run(features, side, hidden, scratch);
        low.resize(self.out.channels_out() * area, 0.0);
        self.out.run(hidden, side, low, scratch);
    }
}

/// Runs `convs` (at least one) in turn over `input` of side `side`; the result lands in
/// `result` (`spare` is scratch). Returns the result's side.
fn chain(
    convs: &[FoldedConv],
    input: &[f32],
    mut side: usize,
    result: &mut Vec<f32>,
    spare: &mut Vec<f32>,
    scratch: &mut Scratch,
) -> usize {
    for (i, conv) in convs.iter().enumerate() {
        let out_side = conv.out_side(side);
        spare.resize(conv.channels_out() * out_side * out_side, 0.0);
        conv.run(if i == 0 { input } else { result }, side, spare, scratch);
        std::mem::swap(result, spare);
        side = out_side;
    }
    side
}

/// Rotates a low-resolution map back by rotation `k`'s angle and upsamples it to the
/// heightmap inside the padding, into `map` (`side x side`).
fn rotate_back(low: &[f32], k: u8, geometry: &Geometry, back: &mut Vec<f32>, map: &mut [f32]) {
    back.clear();
    back.extend(geometry.back_taps(k).iter().map(|taps| {
        taps.index
            .iter()
            .zip(taps.weight)
            .map(|(&i, w)| low[i as usize] * w)
            .sum::<f32>()
    }));
    let s = geometry.low_side();
    let taps = geometry.upsample_taps();
    for (row, &(y0, y1, wy)) in map.chunks_exact_mut(geometry.side()).zip(taps) {
        let (top, bottom) = (&back[y0 as usize * s..], &back[y1 as usize * s..]);
        for (value, &(x0, x1, wx)) in row.iter_mut().zip(taps) {
            let (x0, x1) = (x0 as usize, x1 as usize);
            let upper = top[x0] * (1.0 - wx) + top[x1] * wx;
            let lower = bottom[x0] * (1.0 - wx) + bottom[x1] * wx;
            *value = upper * (1.0 - wy) + lower * wy;
        }
    }
}
