//! Grasps that would squeeze a goal cut by the view's edge out of it. Past a side of the
//! workspace the camera sees none of the goal, so the goal's mask ends at that side as if
//! it were a flat face, and the squeeze guard ([`crate::grasp_squeeze`]) cannot see the
//! slopes there. Pads closing along that side push the goal sideways, across the side, by
//! whatever slopes the hidden part has, and a goal already half out of view leaves it at a
//! nudge; pads closing across the side push it along the jaw axis, along which the view
//! shows where it ends. Judged from the goal's mask, as a robot could judge it.

use std::f32::consts::FRAC_1_SQRT_2;

use sim::{Heightmaps, ObjectId, ROTATIONS, rotation_angle};

/// For each rotation and pixel, laid out `[rotation][row][col]` as [`QMaps`](crate::QMaps):
/// whether a grasp there closes the jaws within 45 degrees of the normal of every side of
/// the workspace that `goal`'s visible mask reaches. Open everywhere when the mask reaches
/// no side.
pub fn grasps_across_view_edge(obs: &Heightmaps, goal: ObjectId) -> Vec<bool> {
    let side = obs.side();
    let mask = obs.goal_mask(goal);
    let last = side - 1;
    // Whether the mask reaches a left or right side (normal along x, the columns) and a
    // top or bottom one (normal along y, the rows): only the border pixels can tell.
    let on_x_side = (0..side).any(|row| mask[row * side] || mask[row * side + last]);
    let on_y_side = (0..side).any(|col| mask[col] || mask[last * side + col]);
    let normals: Vec<[f32; 2]> = [(on_x_side, [1.0, 0.0]), (on_y_side, [0.0, 1.0])]
        .into_iter()
        .filter_map(|(reached, normal)| reached.then_some(normal))
        .collect();
    (0..ROTATIONS)
        .flat_map(|rotation| {
            let angle = rotation_angle(rotation);
            let along = [angle.cos(), angle.sin()];
            // 45 degrees itself (a rotation of its own) stays open, hence the tolerance.
            let across = normals
                .iter()
                .all(|n| (along[0] * n[0] + along[1] * n[1]).abs() > FRAC_1_SQRT_2 - 1e-3);
            std::iter::repeat_n(across, side * side)
        })
        .collect()
}
