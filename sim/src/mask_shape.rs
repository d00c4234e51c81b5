//! The shape of an object's visible pixels, and the scripted grasp and push built on it.

use std::f32::consts::PI;

use crate::camera::Heightmaps;
use crate::primitives::{Action, Primitive, nearest_rotation, rotation_angle};
use crate::tabletop::ObjectId;

/// Where an object is seen and which way it is long: the centroid, size and major-axis angle
/// of its pixels in the id map.
pub struct MaskShape {
    pub row: usize,
    pub col: usize,
    /// How many pixels it covers.
    pub pixels: usize,
    major_angle: f32,
}

impl MaskShape {
    pub fn of(maps: &Heightmaps, goal: ObjectId) -> Option<Self> {
        let pixels: Vec<(f32, f32)> = (0..maps.ids.len())
            .filter(|&i| maps.ids[i] == goal)
            .map(|i| ((i % maps.side()) as f32, (i / maps.side()) as f32))
            .collect();
        if pixels.is_empty() {
            return None;
        }
        let n = pixels.len() as f32;
        let (cx, cy) = pixels
            .iter()
            .fold((0.0, 0.0), |(x, y), p| (x + p.0 / n, y + p.1 / n));
        let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
        for (x, y) in &pixels {
            sxx += (x - cx) * (x - cx);
            syy += (y - cy) * (y - cy);
            sxy += (x - cx) * (y - cy);
        }
        Some(Self {
            row: cy.round() as usize,
            col: cx.round() as usize,
            pixels: pixels.len(),
            // Columns run along x and rows along y, so image angles are world angles.
            major_angle: 0.5 * (2.0 * sxy).atan2(sxx - syy),
        })
    }

    /// Jaws closing across the narrow side, at the centroid.
    pub fn grasp(&self) -> Action {
        Action {
            primitive: Primitive::Grasp,
            rotation: nearest_rotation(self.major_angle + PI / 2.0),
            row: self.row,
            col: self.col,
        }
    }

    /// A push along the goal's long axis, starting 6 cm before its centroid.
    pub fn push(&self, maps: &Heightmaps) -> Action {
        let rotation = nearest_rotation(self.major_angle);
        let angle = rotation_angle(rotation);
        let back = 0.06 / maps.grid.pixel_size();
        let clamp = |v: f32| v.round().clamp(0.0, (maps.side() - 1) as f32) as usize;
        Action {
            primitive: Primitive::Push,
            rotation,
            row: clamp(self.row as f32 - back * angle.sin()),
            col: clamp(self.col as f32 - back * angle.cos()),
        }
    }
}
