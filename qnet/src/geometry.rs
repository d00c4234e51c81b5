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
//! ([`Geometry::add_pixel_weights`]).

use sim::{ROTATIONS, rotation_angle};

use crate::config::QNetConfig;
use crate::error::QNetError;
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
