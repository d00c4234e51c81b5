//! One primitive's Q values for every rotation, as the networks hand them over: plain `f32`s
//! laid out `[rotation][row][col]` over the heightmap.

use crate::error::PolicyError;

/// One primitive's Q maps: `rotations` maps of `side x side`, row-major, rotation-major.
/// Map k scores the action at angle k x 22.5 degrees (the networks rotate back before this).
#[derive(Clone, Debug, PartialEq)]
pub struct QMaps {
    rotations: u8,
    side: usize,
    values: Vec<f32>,
}

impl QMaps {
    /// Wraps `values` laid out `[rotation][row][col]`; their number must be
    /// `rotations * side * side`.
    pub fn new(rotations: u8, side: usize, values: Vec<f32>) -> Result<Self, PolicyError> {
        let expected = rotations as usize * side * side;
        if values.len() != expected {
            return Err(PolicyError::QMapsLength {
                rotations,
                side,
                expected,
                got: values.len(),
            });
        }
        Ok(Self {
            rotations,
            side,
            values,
        })
    }

    /// Number of rotations (maps).
    pub fn rotations(&self) -> u8 {
        self.rotations
    }

    /// Pixels per side of each map.
    pub fn side(&self) -> usize {
        self.side
    }

    /// All values, `[rotation][row][col]`.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// The values to change in place (an ensemble's mean, say); their layout is
    /// [`QMaps::values`]'.
    pub fn values_mut(&mut self) -> &mut [f32] {
        &mut self.values
    }

    /// The Q value of the action at `rotation`, `row`, `col`.
    ///
    /// Panics if any index is out of range (checked one by one, so a row past the edge cannot
    /// alias the next row).
    pub fn get(&self, rotation: u8, row: usize, col: usize) -> f32 {
        assert!(
            rotation < self.rotations && row < self.side && col < self.side,
            "Q index ({rotation}, {row}, {col}) outside {} x {} x {}",
            self.rotations,
            self.side,
            self.side
        );
        self.values[(rotation as usize * self.side + row) * self.side + col]
    }

    /// The highest Q value over all rotations at the pixels where `allowed[row * side + col]`
    /// holds (or, for a mask per rotation, `allowed[(rotation * side + row) * side + col]`),
    /// as `(q, rotation, row, col)`. Ties go to the first in `[rotation][row][col]` order, so
    /// the choice is deterministic; NaN never wins. `None` when no allowed pixel has a value
    /// other than NaN.
    ///
    /// Panics if `allowed` has neither `side * side` nor `rotations * side * side` entries.
    pub fn best_where(&self, allowed: &[bool]) -> Option<(f32, u8, usize, usize)> {
        let pixels = self.side * self.side;
        let per_rotation = allowed.len() == self.values.len() && allowed.len() != pixels;
        assert!(
            per_rotation || allowed.len() == pixels,
            "mask size {} vs Q map size {pixels} (or {} for one mask per rotation)",
            allowed.len(),
            self.values.len()
        );
        if pixels == 0 {
            // `chunks_exact` needs a non-zero size, and empty maps have nothing to pick.
            return None;
        }
        let mut best: Option<(f32, u8, usize, usize)> = None;
        for (rotation, map) in (0..self.rotations).zip(self.values.chunks_exact(pixels)) {
            let at = if per_rotation {
                rotation as usize * pixels
            } else {
                0
            };
            for (i, (&q, _)) in map
                .iter()
                .zip(&allowed[at..at + pixels])
                .enumerate()
                .filter(|(_, (_, a))| **a)
            {
                // Strictly greater: an equal later value does not displace the first, and a
                // NaN compares false either way.
                if !q.is_nan() && best.is_none_or(|(b, ..)| q > b) {
                    best = Some((q, rotation, i / self.side, i % self.side));
                }
            }
        }
        best
    }
}
