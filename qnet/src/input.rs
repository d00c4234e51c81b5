//! An observation as the networks see it: colour, depth and goal-mask planes, normalised as
//! the original (colour / 255 then ImageNet mean and std; depth (d - 0.01) / 0.03; mask 0/1).

use sim::{Heightmaps, ObjectId};

pub const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
pub const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];
pub const DEPTH_OFFSET: f32 = 0.01;
pub const DEPTH_SCALE: f32 = 0.03;

/// The normalised planes of one observation for one goal, row-major `side x side` each.
#[derive(Clone, Debug, PartialEq)]
pub struct NetInput {
    pub side: usize,
    /// Three planes: red, green, blue.
    pub colour: Vec<f32>,
    pub depth: Vec<f32>,
    pub mask: Vec<f32>,
}

/// A colour channel value normalised.
pub fn normalise_colour(value: u8, channel: usize) -> f32 {
    (f32::from(value) / 255.0 - IMAGENET_MEAN[channel]) / IMAGENET_STD[channel]
}

/// A height normalised.
pub fn normalise_depth(height: f32) -> f32 {
    (height - DEPTH_OFFSET) / DEPTH_SCALE
}

impl NetInput {
    /// The planes of `maps` with `goal`'s mask (all zero when the goal is hidden; every
    /// object for the goal-agnostic [`sim::ANY_OBJECT`]).
    pub fn encode(maps: &Heightmaps, goal: ObjectId) -> Self {
        let n = maps.grid.len();
        let mut colour = vec![0.0; 3 * n];
        for (i, rgb) in maps.colour.iter().enumerate() {
            for c in 0..3 {
                colour[c * n + i] = normalise_colour(rgb[c], c);
            }
        }
        Self {
            side: maps.side(),
            colour,
            depth: maps.height.iter().map(|&h| normalise_depth(h)).collect(),
            mask: maps
                .goal_mask(goal)
                .iter()
                .map(|&m| f32::from(u8::from(m)))
                .collect(),
        }
    }

    /// The observation of the scene's mirror image: every plane's rows reversed left to right
    /// (column `c` becomes `side - 1 - c`).
    pub fn mirrored(&self) -> Self {
        let side = self.side;
        let mirror = |plane: &[f32]| -> Vec<f32> {
            plane
                .chunks_exact(side)
                .flat_map(|row| row.iter().rev().copied())
                .collect()
        };
        Self {
            side,
            colour: mirror(&self.colour),
            depth: mirror(&self.depth),
            mask: mirror(&self.mask),
        }
    }

    /// The observation of the scene moved `rows` down and `cols` right (negative: up and
    /// left): pixel `(r, c)` becomes `(r + rows, c + cols)`, what leaves the map is lost and
    /// bare table comes in at the opposite edges.
    pub fn translated(&self, rows: isize, cols: isize) -> Self {
        let side = self.side;
        let table = Self::table_values();
        let from = |to: usize, by: isize| to.checked_add_signed(-by).filter(|&f| f < side);
        let shift = |plane: &[f32], fill: f32| -> Vec<f32> {
            (0..side * side)
                .map(|i| match (from(i / side, rows), from(i % side, cols)) {
                    (Some(r), Some(c)) => plane[r * side + c],
                    _ => fill,
                })
                .collect()
        };
        Self {
            side,
            colour: self
                .colour
                .chunks_exact(side * side)
                .zip(table)
                .flat_map(|(plane, fill)| shift(plane, fill))
                .collect(),
            depth: shift(&self.depth, table[3]),
            mask: shift(&self.mask, table[4]),
        }
    }

    /// The value each plane takes on the bare table, which padding continues.
    pub fn table_values() -> [f32; 5] {
        let table = sim::camera::TABLE_COLOUR;
        [
            normalise_colour(table[0], 0),
            normalise_colour(table[1], 1),
            normalise_colour(table[2], 2),
            normalise_depth(0.0),
            0.0,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3 x 3 input whose every value says where it is: plane p's values are 10 p + i.
    fn numbered() -> NetInput {
        let plane = |offset: f32| (0..9).map(|i| i as f32 + offset).collect::<Vec<_>>();
        NetInput {
            side: 3,
            colour: [plane(0.0), plane(10.0), plane(20.0)].concat(),
            depth: plane(30.0),
            mask: plane(40.0),
        }
    }

    #[test]
    fn a_mirror_image_reverses_every_row_and_twice_is_the_original() {
        let input = numbered();
        let mirror = input.mirrored();
        assert_eq!(
            &mirror.depth,
            &[32.0, 31.0, 30.0, 35.0, 34.0, 33.0, 38.0, 37.0, 36.0]
        );
        assert_eq!(&mirror.colour[9..12], &[12.0, 11.0, 10.0]);
        assert_eq!(&mirror.mask[6..], &[48.0, 47.0, 46.0]);
        assert_eq!(mirror.mirrored(), input);
    }

    #[test]
    fn a_translation_moves_every_plane_and_brings_in_bare_table() {
        let input = numbered();
        let table = NetInput::table_values();
        let (t, e) = (table[3], table[4]);
        let moved = input.translated(1, -1);
        assert_eq!(&moved.depth, &[t, t, t, 31.0, 32.0, t, 34.0, 35.0, t]);
        assert_eq!(&moved.mask, &[e, e, e, 41.0, 42.0, e, 44.0, 45.0, e]);
        assert_eq!(&moved.colour[9..12], &[table[1]; 3]);
        assert_eq!(&moved.colour[21..24], &[21.0, 22.0, table[2]]);
        assert_eq!(input.translated(0, 0), input);
    }
}
