//! Pushes that pass near the goal. A push whose closed gripper sweeps nowhere near the goal
//! cannot change the goal's surroundings, so the paper's reward scores it -0.5 whatever else
//! it moves; drawn uniformly over the table, most exploring pushes are such pushes. Good
//! Robot's SPOT-Q trains such actions' Q towards 0; a mask goes further and never takes them,
//! in training or at test. Judged from the heightmap as the goal guard judges a push
//! ([`crate::push_sweep`]): the band the tool sweeps from its start to its end, widened by
//! `reach` on every side, must hold a goal pixel.

use sim::{Heightmaps, ObjectId};

use crate::push_sweep::{goal_pixels, judge_pushes};

/// For each rotation and start pixel, laid out `[rotation][row][col]` as [`QMaps`](crate::QMaps):
/// whether a push of `push_length` metres from there passes within `reach` metres of a
/// visible goal pixel (along or across its swept band). Every push passes when the goal is
/// not seen.
pub fn pushes_near_goal(
    obs: &Heightmaps,
    goal: ObjectId,
    push_length: f32,
    reach: f32,
) -> Vec<bool> {
    let reach = reach / obs.grid.pixel_size();
    judge_pushes(obs, &goal_pixels(obs, goal), push_length, |push, goal| {
        goal.met(
            push.from - reach,
            push.to + reach,
            push.across,
            push.half + reach,
        )
        .is_some()
    })
}
