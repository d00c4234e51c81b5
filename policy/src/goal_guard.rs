//! Pushes that would carry the goal out of the workspace. An object whose centre leaves the
//! workspace is gone, and with the goal goes the run: on the challenging cases this is how
//! most incomplete runs end. A push is judged from the heightmap alone, as a robot could
//! judge it: the closed gripper sweeps a band [`PUSH_HALF_WIDTH`] either side of the push's
//! line; the nearest goal pixel in that band ahead of the start and within the push's reach
//! is where the tool meets the goal, and the goal is taken to ride on the tool from there to
//! the push's end (clamped to the workspace, as the primitive clamps it). Objects the tool
//! pushes into the goal are not followed: only direct contact is predicted.

use sim::{Heightmaps, ObjectId, ROTATIONS, rotation_angle};

/// Half the width (metres) of the band a push sweeps: the closed RG2's fingers are 20 mm
/// wide across the push, plus a pixel at 2 mm for the goal's edge.
pub const PUSH_HALF_WIDTH: f32 = 0.012;

/// For each rotation and start pixel, laid out [rotation][row][col] as [`QMaps`](crate::QMaps):
/// whether a push of `push_length` metres from there leaves the goal's centre (its visible
/// pixels' mean) at least `margin` metres inside the workspace. Every push keeps it when the
/// goal is not seen.
pub fn pushes_keeping_goal(
    obs: &Heightmaps,
    goal: ObjectId,
    push_length: f32,
    margin: f32,
) -> Vec<bool> {
    let side = obs.side();
    let mut keeps = vec![true; ROTATIONS as usize * side * side];
    // Continuous pixel units: pixel (row, col) is centred at x = col + 0.5, y = row + 0.5,
    // and the workspace spans [0, side] on both axes.
    let goal_pixels = goal_pixels(obs, goal);
    if goal_pixels.is_empty() {
        return keeps;
    }
    let n = goal_pixels.len() as f32;
    let centre = goal_pixels
        .iter()
        .fold([0.0, 0.0], |c, p| [c[0] + p[0] / n, c[1] + p[1] / n]);
    let size = obs.grid.pixel_size();
    let (reach, half, inside, bound) = (
        push_length / size,
        PUSH_HALF_WIDTH / size,
        margin / size,
        side as f32,
    );
    let stays = |p: [f32; 2]| p.iter().all(|&a| (inside..=bound - inside).contains(&a));

    for (rotation, keeps) in (0..ROTATIONS).zip(keeps.chunks_exact_mut(side * side)) {
        let angle = rotation_angle(rotation);
        let along = [angle.cos(), angle.sin()];
        let across = [-angle.sin(), angle.cos()];
        let goal = Profile::new(&goal_pixels, along, across);
        for (i, keep) in keeps.iter_mut().enumerate() {
            let start = pixel_centre(i, side);
            let end = [0, 1].map(|a| (start[a] + reach * along[a]).clamp(0.0, bound));
            let Some(met) = goal.met(dot(start, along), dot(end, along), dot(start, across), half)
            else {
                continue;
            };
            let travel = (dot(end, along) - met).max(0.0);
            *keep = stays([0, 1].map(|a| centre[a] + travel * along[a]));
        }
    }
    keeps
}

/// The goal's visible pixels' centres, in pixel units.
pub(crate) fn goal_pixels(obs: &Heightmaps, goal: ObjectId) -> Vec<[f32; 2]> {
    let side = obs.side();
    (0..side * side)
        .filter(|&i| obs.ids[i] == goal)
        .map(|i| pixel_centre(i, side))
        .collect()
}

/// Pixel `i` (row-major) as (x, y) in pixel units: its column and row, plus half a pixel.
pub(crate) fn pixel_centre(i: usize, side: usize) -> [f32; 2] {
    [(i % side) as f32 + 0.5, (i / side) as f32 + 0.5]
}

pub(crate) fn dot(a: [f32; 2], b: [f32; 2]) -> f32 {
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
    pub(crate) fn new(pixels: &[[f32; 2]], along: [f32; 2], across: [f32; 2]) -> Self {
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
