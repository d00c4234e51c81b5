//! Pushes that pass near the goal. A push whose closed gripper sweeps nowhere near the goal
//! cannot change the goal's surroundings, so the paper's reward scores it -0.5 whatever else
//! it moves; drawn uniformly over the table, most exploring pushes are such pushes. Good
//! Robot's SPOT-Q trains such actions' Q towards 0; a mask goes further and never takes them,
//! in training or at test. Judged from the heightmap as the goal guard judges a push
//! ([`crate::goal_guard`]): the band the tool sweeps from its start to its end, widened by
//! `reach` on every side, must hold a goal pixel.

use sim::{Heightmaps, ObjectId, ROTATIONS, rotation_angle};

use crate::goal_guard::{PUSH_HALF_WIDTH, Profile, dot, goal_pixels, pixel_centre};

/// For each rotation and start pixel, laid out [rotation][row][col] as [`QMaps`](crate::QMaps):
/// whether a push of `push_length` metres from there passes within `reach` metres of a
/// visible goal pixel (along or across its swept band). Every push passes when the goal is
/// not seen.
pub fn pushes_near_goal(
    obs: &Heightmaps,
    goal: ObjectId,
    push_length: f32,
    reach: f32,
) -> Vec<bool> {
    let side = obs.side();
    let goal_pixels = goal_pixels(obs, goal);
    if goal_pixels.is_empty() {
        return vec![true; ROTATIONS as usize * side * side];
    }
    let size = obs.grid.pixel_size();
    let (length, half, reach, bound) = (
        push_length / size,
        PUSH_HALF_WIDTH / size,
        reach / size,
        side as f32,
    );
    let mut near = Vec::with_capacity(ROTATIONS as usize * side * side);
    for rotation in 0..ROTATIONS {
        let angle = rotation_angle(rotation);
        let along = [angle.cos(), angle.sin()];
        let across = [-angle.sin(), angle.cos()];
        let goal = Profile::new(&goal_pixels, along, across);
        near.extend((0..side * side).map(|i| {
            let start = pixel_centre(i, side);
            let end = [0, 1].map(|a| (start[a] + length * along[a]).clamp(0.0, bound));
            goal.met(
                dot(start, along) - reach,
                dot(end, along) + reach,
                dot(start, across),
                half + reach,
            )
            .is_some()
        }));
    }
    near
}
