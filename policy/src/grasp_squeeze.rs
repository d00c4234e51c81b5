//! Grasps that would squeeze the goal out of the jaws. A flat pad closing on a convex outline
//! first touches its farthest point across the pad's width: a corner inside that width meets
//! the pad's face, which pushes straight along the jaw axis; where the outline still widens
//! at the pad's edge, the edge meets a sloping face, which pushes the goal sideways, towards
//! where it is wider. Faces sloping the same way under both pads (a wedge, a roof standing on
//! end) add up, and beyond what the pads' friction holds the goal shoots out of the jaws:
//! in the simulator, a roof standing on end grasped across its 45-degree faces leaves 10-15
//! cm away. Faces sloping opposite ways (a cube grasped across its corners) turn the goal
//! into the jaws instead. Judged from the goal's mask, as a robot could judge it.

use sim::{Heightmaps, Jaws, ObjectId, ROTATIONS, jaws_parts, rotation_angle};

/// The farthest a pad can meet the goal from the tool point, along the jaw axis (metres):
/// beyond the open pads' 50 mm.
const REACH: f32 = 0.06;

/// For each rotation and pixel, laid out `[rotation][row][col]` as [`QMaps`](crate::QMaps):
/// whether a grasp there closes the jaws on faces of `goal` whose slopes, summed with the
/// side each pushes the goal to, stay within twice `friction` (both pads' friction
/// coefficient with the goal). Open everywhere off the goal's visible mask.
pub fn grasps_holding_goal(obs: &Heightmaps, goal: ObjectId, friction: f32) -> Vec<bool> {
    let side = obs.side();
    let mask = obs.goal_mask(goal);
    let pixel = obs.grid.pixel_size();
    let half_pad = jaws_parts(Jaws::Open)
        .iter()
        .map(|p| p.across[1].max(-p.across[0]))
        .fold(0.0, f32::max);
    let samples = (half_pad / pixel).round() as isize;
    // The reach is walked in half pixels. Positions are x along columns and y along rows,
    // in pixels, and `on_goal` takes them in metres from pixel (0, 0)'s centre.
    let steps = (2.0 * REACH / pixel) as usize;
    let on_goal = |x: f32, y: f32| -> bool {
        let (c, r) = ((x / pixel).round(), (y / pixel).round());
        c >= 0.0
            && r >= 0.0
            && (c as usize) < side
            && (r as usize) < side
            && mask[r as usize * side + c as usize]
    };
    let mut holding = vec![true; ROTATIONS as usize * side * side];
    for rotation in 0..ROTATIONS {
        let angle = rotation_angle(rotation);
        let (along, across) = ([angle.cos(), angle.sin()], [-angle.sin(), angle.cos()]);
        for start in (0..side * side).filter(|&i| mask[i]) {
            let (x0, y0) = ((start % side) as f32, (start / side) as f32);
            // How far (metres) the goal reaches from the jaw line `offset` pixels across,
            // towards the pad on `sign`'s side; None where the goal is not on that line.
            let reach = |sign: f32, offset: isize| -> Option<f32> {
                let (x, y) = (
                    x0 + offset as f32 * across[0],
                    y0 + offset as f32 * across[1],
                );
                let at = |k: usize| {
                    let t = sign * k as f32 * 0.5;
                    on_goal(
                        x * pixel + t * along[0] * pixel,
                        y * pixel + t * along[1] * pixel,
                    )
                };
                at(0).then(|| {
                    let last = (1..=steps).take_while(|&k| at(k)).last().unwrap_or(0);
                    0.5 * last as f32 * pixel
                })
            };
            let push: f32 = [1.0f32, -1.0]
                .into_iter()
                .map(|sign| {
                    let reach: Vec<Option<f32>> =
                        (-samples..=samples).map(|s| reach(sign, s)).collect();
                    sideways_push(&reach, pixel)
                })
                .sum();
            if push.abs() > 2.0 * friction {
                holding[rotation as usize * side * side + start] = false;
            }
        }
    }
    holding
}

/// The sideways push of one pad, per unit of its squeeze: `reach[k]` is how far the goal
/// extends towards the pad at the k-th offset across its width (None where the goal is not
/// there). Where the farthest reach is at one of the pad's edges, the slope of the outline
/// from there to the farthest offset the goal covers the other way, signed towards that
/// edge; 0 where it lies within the pad's width.
fn sideways_push(reach: &[Option<f32>], pixel: f32) -> f32 {
    let last = reach.len() - 1;
    let farthest = |k: usize| reach[k].unwrap_or(f32::MIN);
    let top = (0..=last).map(farthest).fold(f32::MIN, f32::max);
    let edge = match (farthest(0) == top, farthest(last) == top) {
        // Flat across the whole pad, or a face at each edge: no side wins.
        (true, true) | (false, false) => return 0.0,
        (true, false) => 0,
        (false, true) => last,
    };
    let other = if edge == 0 {
        (0..=last).rev().find(|&k| reach[k].is_some())
    } else {
        (0..=last).find(|&k| reach[k].is_some())
    }
    .expect("the edge itself is covered");
    if other == edge {
        return 0.0;
    }
    let rise = top - farthest(other);
    let run = edge.abs_diff(other) as f32 * pixel;
    let towards = if edge == 0 { -1.0 } else { 1.0 };
    towards * rise / run
}
