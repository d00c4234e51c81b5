//! Every push as the heightmap sees it, for the masks that judge pushes against the goal
//! ([`crate::goal_guard`], [`crate::push_reach`]): the closed gripper sweeps a band
//! [`PUSH_HALF_WIDTH`] either side of the line from the push's start to its end (clamped to
//! the workspace, as the primitive clamps it), and the goal is its visible pixels.
//! Continuous pixel units: pixel (row, col) is centred at x = col + 0.5, y = row + 0.5, and
//! the workspace spans [0, side] on both axes.

use sim::{Heightmaps, ObjectId, ROTATIONS, rotation_angle};

/// Half the width (metres) of the band a push sweeps: the closed RG2's fingers are 20 mm
/// wide across the push, plus a pixel at 2 mm for the goal's edge.
pub const PUSH_HALF_WIDTH: f32 = 0.012;

/// One push's band, in pixel units.
pub(crate) struct Sweep {
    /// The push's direction (unit).
    pub(crate) along: [f32; 2],
    /// Where the band starts and ends along the push.
    pub(crate) from: f32,
    pub(crate) to: f32,
    /// Where the band's centre line lies across the push.
    pub(crate) across: f32,
    /// The band's half-width.
    pub(crate) half: f32,
}

/// The goal's visible pixels' centres.
pub(crate) fn goal_pixels(obs: &Heightmaps, goal: ObjectId) -> Vec<[f32; 2]> {
    let side = obs.side();
    (0..side * side)
        .filter(|&i| obs.ids[i] == goal)
        .map(|i| pixel_centre(i, side))
        .collect()
}

/// For each rotation and start pixel, laid out `[rotation][row][col]` as
/// [`QMaps`](crate::QMaps): `judge` of the push of `push_length` metres from there, given
/// the goal (`pixels`) seen along it. Every push is `true` when the goal is not seen.
pub(crate) fn judge_pushes(
    obs: &Heightmaps,
    pixels: &[[f32; 2]],
    push_length: f32,
    judge: impl Fn(&Sweep, &Profile) -> bool,
) -> Vec<bool> {
    let side = obs.side();
    if pixels.is_empty() {
        return vec![true; ROTATIONS as usize * side * side];
    }
    let size = obs.grid.pixel_size();
    let (length, half, bound) = (push_length / size, PUSH_HALF_WIDTH / size, side as f32);
    let mut judged = Vec::with_capacity(ROTATIONS as usize * side * side);
    for rotation in 0..ROTATIONS {
        let angle = rotation_angle(rotation);
        let along = [angle.cos(), angle.sin()];
        let across = [-angle.sin(), angle.cos()];
        let goal = Profile::new(pixels, along, across);
        judged.extend((0..side * side).map(|i| {
            let start = pixel_centre(i, side);
            let end = [0, 1].map(|a| (start[a] + length * along[a]).clamp(0.0, bound));
            let sweep = Sweep {
                along,
                from: dot(start, along),
                to: dot(end, along),
                across: dot(start, across),
                half,
            };
            judge(&sweep, &goal)
        }));
    }
    judged
}

/// Pixel `i` (row-major) as (x, y): its column and row, plus half a pixel.
fn pixel_centre(i: usize, side: usize) -> [f32; 2] {
    [(i % side) as f32 + 0.5, (i / side) as f32 + 0.5]
}

fn dot(a: [f32; 2], b: [f32; 2]) -> f32 {
    a[0] * b[0] + a[1] * b[1]
}

/// The goal seen along a push direction: for each one-pixel strip across it, the nearest and
/// farthest of its pixels along the push.
pub(crate) struct Profile {
    /// The first strip's position across the push.
    first: f32,
    /// (nearest, farthest) along the push per strip; `None` where no goal pixel falls.
    strips: Vec<Option<(f32, f32)>>,
}

impl Profile {
    fn new(pixels: &[[f32; 2]], along: [f32; 2], across: [f32; 2]) -> Self {
        let first = pixels
            .iter()
            .map(|&p| dot(p, across))
            .fold(f32::INFINITY, f32::min)
            .floor();
        let mut strips: Vec<Option<(f32, f32)>> = Vec::new();
        for &p in pixels {
            let strip = (dot(p, across) - first) as usize;
            if strip >= strips.len() {
                strips.resize(strip + 1, None);
            }
            let s = dot(p, along);
            let (near, far) = strips[strip].get_or_insert((s, s));
            *near = near.min(s);
            *far = far.max(s);
        }
        Self { first, strips }
    }

    /// Where along the push a tool from `start` to `end` (positions along it), `across` the
    /// push with half-width `half`, first meets the goal; `None` if it does not.
    pub(crate) fn met(&self, start: f32, end: f32, across: f32, half: f32) -> Option<f32> {
        let from = (across - half - self.first).floor().max(0.0) as usize;
        let to = (across + half - self.first).floor();
        if to < 0.0 {
            return None;
        }
        let to = (to as usize).min(self.strips.len().saturating_sub(1));
        self.strips
            .get(from..=to)?
            .iter()
            .flatten()
            .filter(|&&(_, far)| far >= start)
            .map(|&(near, _)| near.max(start))
            .filter(|&met| met <= end)
            .reduce(f32::min)
    }
}
