//! Pushes that would carry the goal's centre out of the workspace. A goal past the edge is
//! mostly out of the camera's view, and once none of it is seen it is gone, and with it the
//! run: on the challenging cases this is how most incomplete runs end. A push is judged
//! from the heightmap alone, as a robot could judge it ([`crate::push_sweep`]): the nearest
//! goal pixel in the band the push sweeps, ahead of the start and within the push's reach,
//! is where the tool meets the goal, and the goal is taken to ride on the tool from there
//! to the push's end. Objects the tool pushes into the goal are not followed: only direct
//! contact is predicted.

use sim::{Heightmaps, ObjectId};

use crate::push_sweep::{goal_pixels, judge_pushes};

/// For each rotation and start pixel, laid out `[rotation][row][col]` as [`QMaps`](crate::QMaps):
/// whether a push of `push_length` metres from there leaves the goal's centre (its visible
/// pixels' mean) at least `margin` metres inside the workspace. Every push keeps it when the
/// goal is not seen.
pub fn pushes_keeping_goal(
    obs: &Heightmaps,
    goal: ObjectId,
    push_length: f32,
    margin: f32,
) -> Vec<bool> {
    let pixels = goal_pixels(obs, goal);
    let n = pixels.len() as f32;
    let centre = pixels
        .iter()
        .fold([0.0, 0.0], |c, p| [c[0] + p[0] / n, c[1] + p[1] / n]);
    let (inside, bound) = (margin / obs.grid.pixel_size(), obs.side() as f32);
    let stays = |p: [f32; 2]| p.iter().all(|&a| (inside..=bound - inside).contains(&a));
    judge_pushes(obs, &pixels, push_length, |push, goal| {
        let Some(met) = goal.met(push.from, push.to, push.across, push.half) else {
            return true;
        };
        let travel = (push.to - met).max(0.0);
        stays([0, 1].map(|a| centre[a] + travel * push.along[a]))
    })
}
