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

    #[test]
    fn a_mirror_image_reverses_every_row_and_twice_is_the_original() {
        let side = 3;
        let plane = |offset: f32| (0..9).map(|i| i as f32 + offset).collect::<Vec<_>>();
        let input = NetInput {
            side,
            colour: [plane(0.0), plane(10.0), plane(20.0)].concat(),
            depth: plane(30.0),
            mask: plane(40.0),
        };
        let mirror = input.mirrored();
        assert_eq!(
            &mirror.depth,
            &[32.0, 31.0, 30.0, 35.0, 34.0, 33.0, 38.0, 37.0, 36.0]
        );
        assert_eq!(&mirror.colour[9..12], &[12.0, 11.0, 10.0]);
        assert_eq!(&mirror.mask[6..], &[48.0, 47.0, 46.0]);
        assert_eq!(mirror.mirrored(), input);
    }
}
