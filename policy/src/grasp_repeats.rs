//! Grasps not to make again. Frozen nets in a scene that a grasp which picked nothing left as
//! it was rank that grasp first again; the test loop (`eval --avoid-failed-grasps`) remembers
//! such grasps until a push changes the scene, and the grasp region closes around each. The
//! jaws are symmetric, so a grasp turned half round is the same grasp.

use sim::{Action, Heightmaps, ROTATIONS};

/// A grasp within this distance (metres) of one that picked nothing, at its rotation or the
/// next either side, either way along the jaw line, is taken as the same grasp again.
pub const REPEAT_RADIUS: f32 = 0.01;

/// The grasp region (one mask for every rotation) with the grasps near `failed` ones closed,
/// per rotation, laid out `[rotation][row][col]` as [`QMaps`](crate::QMaps); `region` as it
/// was when nothing failed or nothing would be left open.
pub fn grasps_not_repeating(region: Vec<bool>, failed: &[Action], obs: &Heightmaps) -> Vec<bool> {
    if failed.is_empty() {
        return region;
    }
    let side = obs.side() as isize;
    let reach = (REPEAT_RADIUS / obs.grid.pixel_size()) as isize;
    let rotations = ROTATIONS as isize;
    let mut open = region.repeat(ROTATIONS as usize);
    for grasp in failed {
        let (row, col) = (grasp.row as isize, grasp.col as isize);
        for turn in [0, rotations / 2]
            .into_iter()
            .flat_map(|half| [half - 1, half, half + 1])
        {
            let rotation = (grasp.rotation as isize + turn).rem_euclid(rotations);
            for r in (row - reach).max(0)..=(row + reach).min(side - 1) {
                for c in (col - reach).max(0)..=(col + reach).min(side - 1) {
                    if (r - row).pow(2) + (c - col).pow(2) <= reach * reach {
                        open[((rotation * side + r) * side + c) as usize] = false;
                    }
                }
            }
        }
    }
    if open.contains(&true) { open } else { region }
}
