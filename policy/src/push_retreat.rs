//! Pushes started farther back where their jaws would come down on the goal. The landing
//! guard judges a push's start on the observation's pixels, whose heights are the surface at
//! their centres, so the goal's corner can reach under the closed jaws between pixel centres;
//! the descent then squeezes the goal until the fingers throw it, which is how most goals
//! still lost on the challenging cases leave. Seen on the scene rendered finer, such a push
//! is not closed (closing them had worse pushes chosen instead) but started farther back
//! along its own direction, at the nearest start clear of the goal: the same push, meeting
//! the goal a few millimetres later.

use sim::{ROTATIONS, rotation_angle};

/// Where the push at `rotation` from `[row, col]` starts instead: itself where
/// `clear_of_goal` holds it, else the first start a whole number of pixels back along the
/// push, at most `distance` pixels, that both `allowed` (the push region: one `side * side`
/// mask for every rotation, or one per rotation) and `clear_of_goal` (one per rotation) hold;
/// itself where none does.
pub fn push_start_clear_of_goal(
    rotation: u8,
    [row, col]: [usize; 2],
    allowed: &[bool],
    clear_of_goal: &[bool],
    side: usize,
    distance: f32,
) -> [usize; 2] {
    let pixels = side * side;
    assert_eq!(clear_of_goal.len(), ROTATIONS as usize * pixels);
    let at = |[row, col]: [usize; 2]| rotation as usize * pixels + row * side + col;
    if clear_of_goal[at([row, col])] {
        return [row, col];
    }
    let per_rotation = allowed.len() == ROTATIONS as usize * pixels;
    let open = |start: [usize; 2]| {
        let i = start[0] * side + start[1];
        clear_of_goal[at(start)] && allowed[if per_rotation { at(start) } else { i }]
    };
    let angle = rotation_angle(rotation);
    let (along_col, along_row) = (angle.cos(), angle.sin());
    (1..=distance.floor() as usize)
        .filter_map(|back| {
            let back = back as f32;
            let r = row as f32 - (back * along_row).round();
            let c = col as f32 - (back * along_col).round();
            let inside = |a: f32| (0.0..side as f32).contains(&a);
            (inside(r) && inside(c)).then_some([r as usize, c as usize])
        })
        .find(|&start| open(start))
        .unwrap_or([row, col])
}
