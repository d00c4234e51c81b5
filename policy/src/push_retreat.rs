//! Pushes started farther back where their jaws would come down on the goal. The landing
//! guard judges a push's start on the observation's pixels, whose heights are the surface at
//! their centres, so the goal's corner can reach under the closed jaws between pixel centres;
//! the descent then squeezes the goal until the fingers throw it, which is how most goals
//! still lost on the challenging cases leave. Seen on the scene rendered finer, such a push
//! is not closed (closing them had worse pushes chosen instead) but started farther back
//! along its own direction, at the nearest start clear of the goal: the same push, meeting
//! the goal a few millimetres later.

use std::iter::once;

use sim::{Heightmaps, ObjectId, ROTATIONS, rotation_angle};

use crate::jaws_landing::pushes_landing_clear_of_at;

/// Where the push at `rotation` from `[row, col]` starts instead: itself where its closed
/// jaws, widened by `margin`, come down clear of `goal` as `view` (the scene rendered finer)
/// sees it; else the first start a whole number of pixels back along the push, at most
/// `distance` metres, that `allowed` (the push region: one `side * side` mask for every
/// rotation, or one per rotation) holds and whose jaws come down clear of the goal; itself
/// where none does.
#[allow(clippy::too_many_arguments)]
pub fn push_start_clear_of_goal(
    obs: &Heightmaps,
    view: &Heightmaps,
    goal: ObjectId,
    margin: f32,
    rotation: u8,
    [row, col]: [usize; 2],
    allowed: &[bool],
    distance: f32,
) -> [usize; 2] {
    let side = obs.side();
    let pixels = side * side;
    let map = if allowed.len() == ROTATIONS as usize * pixels {
        rotation as usize * pixels
    } else {
        0
    };
    let angle = rotation_angle(rotation);
    let (along_col, along_row) = (angle.cos(), angle.sin());
    let backs = (1..=(distance / obs.grid.pixel_size()).floor() as usize).filter_map(|back| {
        let back = back as f32;
        let r = row as f32 - (back * along_row).round();
        let c = col as f32 - (back * along_col).round();
        let inside = |a: f32| (0.0..side as f32).contains(&a);
        (inside(r) && inside(c)).then_some([r as usize, c as usize])
    });
    let starts: Vec<[usize; 2]> = once([row, col])
        .chain(backs.filter(|&[r, c]| allowed[map + r * side + c]))
        .collect();
    let clear = pushes_landing_clear_of_at(obs, view, goal, margin, &starts);
    let clear_at = |[r, c]: [usize; 2]| clear[rotation as usize * pixels + r * side + c];
    if clear_at([row, col]) {
        return [row, col];
    }
    starts[1..]
        .iter()
        .copied()
        .find(|&start| clear_at(start))
        .unwrap_or([row, col])
}
