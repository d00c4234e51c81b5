//! The rotations around the networks: the input is padded (so no corner is lost) and
//! rotated by -theta before the nets, and each Q map rotated back by +theta after them.
//!
//! In pixel coordinates (x along columns, y along rows) the action at angle theta points
//! along (cos theta, sin theta). Rotating the input by -theta turns that direction into +x,
//! so a net only ever learns to push (or close its jaws) along +x. The inputs need no
//! gradient, so they are rotated here by a precomputed nearest-neighbour gather (as the
//! original's nearest sampling); the outputs are rotated back with burn's bilinear
//! `grid_sample`, or, in the CPU inference form, by the same bilinear taps precomputed here
//! ([`Geometry::back_taps`]). The learner, which needs one pixel per map, reads it off the
//! low-resolution map through those taps and the upsampling's, folded together
//! ([`Geometry::add_pixel_weights`]). On a GPU the inputs are rotated there, by the same
//! gather from each input sent once ([`Geometry::rotated_planes`]).
//!
//! Its tests take it past 400 lines; the code itself is under 400.

use std::sync::OnceLock;

use burn::prelude::*;
use sim::{ROTATIONS, rotation_angle};

use crate::config::QNetConfig;
use crate::error::QNetError;
use crate::fresh::zeroed_triple;
use crate::input::NetInput;

/// A padded pixel whose source lies outside the image.
const OUTSIDE: u32 = u32::MAX;

/// The padding and rotation tables for one heightmap size and net shape.
#[derive(Clone, Debug)]
pub struct Geometry {
    side: usize,
    padded: usize,
    downsample: usize,
    /// Per rotation, for each pixel of the padded rotated input, its source pixel in the
    /// unpadded image (row-major), or `OUTSIDE`.
    sources: Vec<Vec<u32>>,
    /// Per rotation, for each low-resolution pixel rotated back, its bilinear taps.
    back: Vec<Vec<Taps>>,
    /// For each row (and column) of the heightmap, the two low-resolution rows the
    /// upsampling blends and the second one's weight.
    upsample: Vec<(u32, u32, f32)>,
    /// `sources` on the device the nets run on when that is not the CPU, made at its first
    /// use there ([`Geometry::rotated_planes`]): one for a device without autodiff (acting,
    /// a learner's next-state values), one for it with autodiff (training). Devices compare
    /// equal with and without autodiff, and an index made for the one would carry its
    /// autodiff into the other's forward.
    device_sources: [OnceLock<(Device, Tensor<2, Int>)>; 2],
}

/// Four pixels of a map, row-major indices, and their bilinear weights.
#[derive(Clone, Copy, Debug)]
pub struct Taps {
    pub index: [u32; 4],
    pub weight: [f32; 4],
}

impl Geometry {
    pub fn new(side: usize, config: &QNetConfig) -> Self {
        let downsample = config.downsample();
        let diagonal = (side as f32 * std::f32::consts::SQRT_2).ceil() as usize;
        // A multiple of the downsampling, and of 2 past it so the image sits centred.
        let step = downsample.max(2);
        let mut padded = diagonal.div_ceil(step) * step;
        if (padded - side) % 2 == 1 {
            padded += step;
        }
        let offset = (padded - side) / 2;
        let centre = padded as f32 / 2.0;
        let sources = (0..ROTATIONS)
            .map(|k| {
                let (sin, cos) = rotation_angle(k).sin_cos();
                let mut table = Vec::with_capacity(padded * padded);
                for row in 0..padded {
                    for col in 0..padded {
                        let (dx, dy) = (col as f32 + 0.5 - centre, row as f32 + 0.5 - centre);
                        let x = (centre + cos * dx - sin * dy).floor() - offset as f32;
                        let y = (centre + sin * dx + cos * dy).floor() - offset as f32;
                        let inside = x >= 0.0 && y >= 0.0 && x < side as f32 && y < side as f32;
                        table.push(if inside {
                            (y as usize * side + x as usize) as u32
                        } else {
                            OUTSIDE
                        });
                    }
                }
                table
            })
            .collect();
        let mut geometry = Self {
            side,
            padded,
            downsample,
            sources,
            back: Vec::new(),
            upsample: Vec::new(),
            device_sources: Default::default(),
        };
        geometry.back = (0..ROTATIONS).map(|k| geometry.taps_of(k)).collect();
        geometry.upsample = geometry.upsample_of();
        geometry
    }

    /// `back_grid`'s samples of rotation `k` as bilinear taps, as `grid_sample` reads them
    /// (pixel centres, corners not aligned, coordinates clamped to the border).
    fn taps_of(&self, k: u8) -> Vec<Taps> {
        let s = self.low_side();
        let to_pixel = |g: f32| ((g + 1.0) * s as f32 / 2.0 - 0.5).clamp(0.0, (s - 1) as f32);
        self.back_grid(&[k])
            .chunks_exact(2)
            .map(|g| {
                let (x, y) = (to_pixel(g[0]), to_pixel(g[1]));
                let (x0, y0) = (x.floor() as usize, y.floor() as usize);
                let (x1, y1) = ((x0 + 1).min(s - 1), (y0 + 1).min(s - 1));
                let (fx, fy) = (x - x0 as f32, y - y0 as f32);
                let at = |row: usize, col: usize| (row * s + col) as u32;
                Taps {
                    index: [at(y0, x0), at(y0, x1), at(y1, x0), at(y1, x1)],
                    weight: [
                        (1.0 - fx) * (1.0 - fy),
                        fx * (1.0 - fy),
                        (1.0 - fx) * fy,
                        fx * fy,
                    ],
                }
            })
            .collect()
    }

    /// Bilinear upsampling from the low side to the padded side (pixel centres, corners not
    /// aligned), for the heightmap's rows inside the padding.
    fn upsample_of(&self) -> Vec<(u32, u32, f32)> {
        let (s, p) = (self.low_side(), self.padded);
        (self.offset()..self.offset() + self.side)
            .map(|i| {
                let x = ((i as f32 + 0.5) * s as f32 / p as f32 - 0.5).max(0.0);
                let low = (x.floor() as usize).min(s - 1);
                let high = (low + 1).min(s - 1);
                (low as u32, high as u32, (x - low as f32).max(0.0))
            })
            .collect()
    }

    /// Per low-resolution pixel of a map rotated back by rotation `k`'s angle, the pixels of
    /// the net's output it blends (what [`Geometry::back_grid`] samples).
    pub fn back_taps(&self, k: u8) -> &[Taps] {
        &self.back[k as usize]
    }

    /// Per row (and column) of the heightmap, the two low-resolution rows (columns) of a
    /// rotated-back map its upsampling blends and the second one's weight.
    pub fn upsample_taps(&self) -> &[(u32, u32, f32)] {
        &self.upsample
    }

    /// The heightmap side this geometry is for.
    pub fn side(&self) -> usize {
        self.side
    }

    /// Side of the padded input the nets see.
    pub fn padded(&self) -> usize {
        self.padded
    }

    /// Side of the Q maps the nets produce before upsampling.
    pub fn low_side(&self) -> usize {
        self.padded / self.downsample
    }

    /// Where the heightmap starts inside the padded square (both axes).
    pub fn offset(&self) -> usize {
        (self.padded - self.side) / 2
    }

    /// Checks an input and a rotation against this geometry.
    pub fn check(&self, input: &NetInput, rotation: u8) -> Result<(), QNetError> {
        if input.side != self.side {
            return Err(QNetError::Side {
                got: input.side,
                want: self.side,
            });
        }
        if rotation >= ROTATIONS {
            return Err(QNetError::Rotation(rotation));
        }
        Ok(())
    }

    /// Appends the input planes padded and rotated by -theta to `[colour, depth, mask]`
    /// (`3 x P x P`, `P x P` and `P x P` values), which batch as `[n, c, P, P]`.
    pub fn rotate_input(&self, input: &NetInput, rotation: u8, out: [&mut Vec<f32>; 3]) {
        let area = self.padded * self.padded;
        let [colour, depth, mask] = out;
        let (c, d, m) = (colour.len(), depth.len(), mask.len());
        colour.resize(c + 3 * area, 0.0);
        depth.resize(d + area, 0.0);
        mask.resize(m + area, 0.0);
        self.rotate_input_into(
            input,
            rotation,
            [&mut colour[c..], &mut depth[d..], &mut mask[m..]],
        );
    }

    /// [`Geometry::rotate_input`] into `[colour, depth, mask]` slices of exactly
    /// `3 x P x P`, `P x P` and `P x P` values.
    pub fn rotate_input_into(&self, input: &NetInput, rotation: u8, out: [&mut [f32]; 3]) {
        let n = self.side * self.side;
        let table = NetInput::table_values();
        let planes: [&[f32]; 5] = [
            &input.colour[..n],
            &input.colour[n..2 * n],
            &input.colour[2 * n..],
            &input.depth,
            &input.mask,
        ];
        let sources = &self.sources[rotation as usize];
        let area = sources.len();
        let [colour, depth, mask] = out;
        assert!(
            colour.len() == 3 * area && depth.len() == area && mask.len() == area,
            "rotated planes of 3 x {area}, {area} and {area} values"
        );
        // One pass over the table writes all five planes.
        let (red, rest) = colour.split_at_mut(area);
        let (green, blue) = rest.split_at_mut(area);
        let mut targets = [red, green, blue, depth, mask];
        for (i, &s) in sources.iter().enumerate() {
            for ((target, plane), outside) in targets.iter_mut().zip(&planes).zip(&table) {
                target[i] = if s == OUTSIDE {
                    *outside
                } else {
                    plane[s as usize]
                };
            }
        }
    }

    /// The nets' input for `passes` (an input and the rotation it is turned by, each): the
    /// planes padded and rotated by -theta, colour `[m, 3, P, P]`, depth and mask
    /// `[m, 1, P, P]`, on `device`. On the CPU they are gathered here; on any other device
    /// (a GPU's) each distinct input is sent once as it is, a sixteenth of its 16 rotations'
    /// padded planes, and gathered there through the rotation tables, which stay on that
    /// device.
    pub fn rotated_planes(&self, passes: &[(&NetInput, u8)], device: &Device) -> [Tensor<4>; 3] {
        if device.clone().without_autodiff() == Device::flex() {
            self.rotated_here(passes, device)
        } else {
            self.rotated_there(passes, device)
        }
    }

    /// [`Geometry::rotated_planes`] gathered on this machine's cores.
    fn rotated_here(&self, passes: &[(&NetInput, u8)], device: &Device) -> [Tensor<4>; 3] {
        let (m, p) = (passes.len(), self.padded);
        let area = p * p;
        let planes = zeroed_triple(m, [3 * area, area, area], |i, planes| {
            let (input, rotation) = passes[i];
            self.rotate_input_into(input, rotation, planes);
        });
        let [colour, depth, mask] = planes;
        let plane = |values: Vec<f32>, channels: usize| {
            Tensor::<4>::from_data(TensorData::new(values, [m, channels, p, p]), device)
        };
        [plane(colour, 3), plane(depth, 1), plane(mask, 1)]
    }

    /// [`Geometry::rotated_planes`] gathered on `device` from each distinct input's planes.
    fn rotated_there(&self, passes: &[(&NetInput, u8)], device: &Device) -> [Tensor<4>; 3] {
        let (m, p) = (passes.len(), self.padded);
        // Each distinct input's pixels, then one of the bare table's (what a padded pixel
        // reads): colour three values a pixel, depth and mask one.
        let n = self.side * self.side;
        let stride = n + 1;
        let mut inputs: Vec<&NetInput> = Vec::new();
        let (mut turns, mut offsets) = (Vec::with_capacity(m), Vec::with_capacity(m));
        for &(input, rotation) in passes {
            let j = inputs
                .iter()
                .position(|&other| std::ptr::eq(other, input))
                .unwrap_or_else(|| {
                    inputs.push(input);
                    inputs.len() - 1
                });
            turns.push(i64::from(rotation));
            offsets.push((j * stride) as i64);
        }
        let table = NetInput::table_values();
        let mut planes =
            [3, 1, 1].map(|channels| Vec::with_capacity(inputs.len() * stride * channels));
        for input in &inputs {
            let [colour, depth, mask] = &mut planes;
            let c = &input.colour;
            colour.extend((0..n).flat_map(|i| [c[i], c[n + i], c[2 * n + i]]));
            colour.extend(&table[..3]);
            depth.extend(&input.depth);
            depth.push(table[3]);
            mask.extend(&input.mask);
            mask.push(table[4]);
        }
        // Every rotation of one input in order is the table itself.
        let sources = self.device_sources(device);
        let mut index = if turns.iter().copied().eq(0..i64::from(ROTATIONS)) {
            sources
        } else {
            sources.select(0, Tensor::<1, Int>::from_ints(turns.as_slice(), device))
        };
        if inputs.len() > 1 {
            index = index + Tensor::<1, Int>::from_ints(offsets.as_slice(), device).reshape([m, 1]);
        }
        // Gathered a pixel at a time, its channels side by side: the channels-last layout a
        // GPU's convolutions take.
        let index = index.reshape([m * p * p]);
        planes.map(|values| {
            let channels = values.len() / (inputs.len() * stride);
            Tensor::<2>::from_data(
                TensorData::new(values, [inputs.len() * stride, channels]),
                device,
            )
            .select(0, index.clone())
            .reshape([m, p, p, channels])
            .permute([0, 3, 1, 2])
        })
    }

    /// `sources` on `device` as indices into an input's pixels, `n` (the table's value
    /// after them) for a pixel outside the image: `[ROTATIONS, P x P]`. Kept for the first
    /// device asked for with autodiff and the first without, made afresh for any other.
    fn device_sources(&self, device: &Device) -> Tensor<2, Int> {
        let make = || {
            let outside = (self.side * self.side) as i64;
            let indices: Vec<i64> = self
                .sources
                .iter()
                .flatten()
                .map(|&s| if s == OUTSIDE { outside } else { i64::from(s) })
                .collect();
            let shape = [self.sources.len(), self.padded * self.padded];
            Tensor::<2, Int>::from_data(TensorData::new(indices, shape), device)
        };
        let kind = &self.device_sources[usize::from(device.is_autodiff())];
        let (kept, sources) = kind.get_or_init(|| (device.clone(), make()));
        if kept == device {
            sources.clone()
        } else {
            make()
        }
    }

    /// Adds to `weights` (`s x s`, a low-resolution map's pixels) each pixel's share of the
    /// value at heightmap pixel `(row, col)` once the map is rotated back by rotation `k`'s
    /// angle and upsampled: the bilinear upsampling's four taps of the rotated-back map,
    /// each of them the back rotation's four taps, so at most 16 pixels.
    pub fn add_pixel_weights(&self, k: u8, (row, col): (usize, usize), weights: &mut [f32]) {
        let s = self.low_side();
        let back = self.back_taps(k);
        let (y0, y1, wy) = self.upsample[row];
        let (x0, x1, wx) = self.upsample[col];
        for (y, fy) in [(y0, 1.0 - wy), (y1, wy)] {
            for (x, fx) in [(x0, 1.0 - wx), (x1, wx)] {
                let taps = &back[y as usize * s + x as usize];
                for (&index, &weight) in taps.index.iter().zip(&taps.weight) {
                    weights[index as usize] += fy * fx * weight;
                }
            }
        }
    }

    /// The sampling grid that rotates low-resolution Q maps back by +theta, `[n, s, s, 2]`
    /// in grid_sample's normalised coordinates (x then y, pixel centres, corners not
    /// aligned).
    pub fn back_grid(&self, rotations: &[u8]) -> Vec<f32> {
        let s = self.low_side();
        let mut grid = Vec::with_capacity(rotations.len() * s * s * 2);
        for &k in rotations {
            let (sin, cos) = rotation_angle(k).sin_cos();
            for row in 0..s {
                for col in 0..s {
                    let u = (col as f32 + 0.5) / s as f32 * 2.0 - 1.0;
                    let v = (row as f32 + 0.5) / s as f32 * 2.0 - 1.0;
                    grid.push(cos * u + sin * v);
                    grid.push(-sin * u + cos * v);
                }
            }
        }
        grid
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `side x side` input whose every value differs, no scene needed.
    fn numbered(side: usize, offset: f32) -> NetInput {
        let plane = |planes: usize, from: f32| {
            (0..planes * side * side)
                .map(|i| from + i as f32 / 1000.0)
                .collect()
        };
        NetInput {
            side,
            colour: plane(3, offset),
            depth: plane(1, offset + 10.0),
            mask: plane(1, offset + 20.0),
        }
    }

    #[test]
    fn the_gather_a_device_runs_gives_the_planes_rotated_here() {
        // Every rotation of one input in order (the table itself), and rotations out of
        // order over two inputs (rows picked and offset per input).
        let geometry = Geometry::new(12, &QNetConfig::default());
        let (a, b) = (numbered(12, 0.0), numbered(12, 100.0));
        let every: Vec<(&NetInput, u8)> = (0..ROTATIONS).map(|k| (&a, k)).collect();
        let mixed = [(&b, 3), (&a, 3), (&b, 0), (&a, 15), (&b, 9)];
        let device = Device::flex();
        let values =
            |planes: [Tensor<4>; 3]| planes.map(|t| t.into_data().try_to_vec::<f32>().unwrap());
        for passes in [&every[..], &mixed] {
            let here = values(geometry.rotated_here(passes, &device));
            let there = values(geometry.rotated_there(passes, &device));
            assert_eq!(there, here);
        }
    }
}
