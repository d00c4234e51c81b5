//! Where each primitive may act, as masks the argmax and the exploration draw both read: the
//! grasp region (the goal mask less its rim), narrowed to the grasps the policy may choose
//! (no failed grasp again, the grasp landing guard, the squeeze guard, the view edge
//! guard), and the push region (the valid push starts, narrowed by the goal guard, the push
//! reach and the landing guard in that order).

use sim::{Action, Heightmaps, ObjectId, ROTATIONS};

use crate::config::PolicyConfig;
use crate::goal_guard::pushes_keeping_goal;
use crate::grasp_repeats::grasps_not_repeating;
use crate::grasp_squeeze::grasps_holding_goal;
use crate::grasp_view_edge::grasps_across_view_edge;
use crate::jaws_landing::{grasps_landing_clear, pushes_landing_clear, pushes_landing_clear_of};
use crate::push_reach::pushes_near_goal;

/// A push may only start where the surface is lower than this (metres): "pushes may not
/// start on top of an object during training". Every block rests at least 2.5 cm tall, so
/// only the sloped or rounded fringe of an object can be lower.
pub const PUSH_START_MAX_HEIGHT: f32 = 0.01;

/// Where a grasp may go and where the goal's grasp Q is read: the goal mask less its rim
/// `margin` metres wide (its deepest pixels where the rim would take all of it); if the goal
/// is hidden, every object pixel (so the policy can uncover it by grasping what lies on
/// top); if the table is bare, everywhere. Row-major, `side * side`.
pub fn grasp_region(obs: &Heightmaps, goal: ObjectId, margin: f32) -> Vec<bool> {
    let mask = obs.goal_mask(goal);
    if mask.contains(&true) {
        let rim = (margin / obs.grid.pixel_size()).round() as u32;
        return without_rim(&mask, obs.side(), rim);
    }
    let objects: Vec<bool> = obs.ids.iter().map(|&id| id != 0).collect();
    if objects.contains(&true) {
        return objects;
    }
    vec![true; obs.ids.len()]
}

/// Where a grasp may go, laid out as [`QMaps::best_where`](crate::QMaps::best_where) reads
/// it: the [`grasp_region`] less the grasps near `failed` ones ([`grasps_not_repeating`]);
/// under the config's `grasp_landing_guard`, of those, the ones whose open jaws come down
/// clear of every object ([`grasps_landing_clear`]); under its `squeeze_guard`, of those,
/// the ones that do not squeeze the goal out of the jaws ([`grasps_holding_goal`]); under
/// its `view_edge_guard`, of those, the ones closing across the sides of the workspace the
/// goal reaches ([`grasps_across_view_edge`]). A mask that would leave no grasp is not
/// applied, nor any after it.
pub fn grasp_choices(
    obs: &Heightmaps,
    goal: ObjectId,
    config: &PolicyConfig,
    failed: &[Action],
) -> Vec<bool> {
    let within = grasp_region(obs, goal, config.grasp_margin);
    let masks: Vec<Vec<bool>> = [
        config
            .grasp_landing_guard
            .map(|margin| grasps_landing_clear(obs, margin, &within)),
        config
            .squeeze_guard
            .map(|friction| grasps_holding_goal(obs, goal, friction)),
        config
            .view_edge_guard
            .then(|| grasps_across_view_edge(obs, goal)),
    ]
    .into_iter()
    .flatten()
    .collect();
    let region = grasps_not_repeating(within, failed, obs);
    if masks.is_empty() {
        return region;
    }
    let per_rotation = if region.len() == obs.ids.len() {
        region.repeat(ROTATIONS as usize)
    } else {
        region
    };
    narrowed_in_turn(per_rotation, masks)
}

/// `region` narrowed by each of `masks` in turn, until one would leave nothing open.
fn narrowed_in_turn(mut region: Vec<bool>, masks: Vec<Vec<bool>>) -> Vec<bool> {
    for mask in masks {
        match narrowed(&region, &mask) {
            Some(both) => region = both,
            None => break,
        }
    }
    region
}

/// `region` and `mask` both, where that leaves something open.
fn narrowed(region: &[bool], mask: &[bool]) -> Option<Vec<bool>> {
    let both: Vec<bool> = region.iter().zip(mask).map(|(&r, &m)| r && m).collect();
    both.contains(&true).then_some(both)
}

/// The pixels of `mask` more than `rim` steps (in any of 8 directions) from a pixel outside
/// it or from the map's border; where there are none, its deepest pixels.
fn without_rim(mask: &[bool], side: usize, rim: u32) -> Vec<bool> {
    if rim == 0 {
        return mask.to_vec();
    }
    let depth = chessboard_depth(mask, side);
    let keep = (rim + 1).min(depth.iter().copied().max().unwrap_or(0));
    depth.iter().map(|&d| d > 0 && d >= keep).collect()
}

/// Each pixel's chessboard distance to the nearest pixel outside `mask` (the map's border
/// counts as outside): 0 outside, 1 on the rim. Two raster passes.
fn chessboard_depth(mask: &[bool], side: usize) -> Vec<u32> {
    let mut depth: Vec<u32> = mask.iter().map(|&m| if m { u32::MAX } else { 0 }).collect();
    let at = |depth: &[u32], r: isize, c: isize| -> u32 {
        if r < 0 || c < 0 || r >= side as isize || c >= side as isize {
            0
        } else {
            depth[r as usize * side + c as usize]
        }
    };
    let mut pass = |order: &mut dyn Iterator<Item = usize>, neighbours: [(isize, isize); 4]| {
        for i in order {
            if depth[i] == 0 {
                continue;
            }
            let (r, c) = ((i / side) as isize, (i % side) as isize);
            let nearest = neighbours
                .iter()
                .map(|&(dr, dc)| at(&depth, r + dr, c + dc))
                .min()
                .expect("four neighbours");
            depth[i] = depth[i].min(nearest.saturating_add(1));
        }
    };
    pass(&mut (0..mask.len()), [(-1, -1), (-1, 0), (-1, 1), (0, -1)]);
    pass(
        &mut (0..mask.len()).rev(),
        [(1, 1), (1, 0), (1, -1), (0, 1)],
    );
    depth
}

/// Where a push may start: pixels lower than [`PUSH_START_MAX_HEIGHT`], i.e. not on top of
/// an object; everywhere if the objects cover every pixel. Row-major, `side * side`.
pub fn valid_push_starts(obs: &Heightmaps) -> Vec<bool> {
    let starts: Vec<bool> = obs
        .height
        .iter()
        .map(|&h| h < PUSH_START_MAX_HEIGHT)
        .collect();
    if starts.contains(&true) {
        starts
    } else {
        vec![true; starts.len()]
    }
}

/// Where a push may go, laid out as [`QMaps::best_where`](crate::QMaps::best_where) reads it: the
/// [`valid_push_starts`] for every rotation; under the config's `goal_guard`, per rotation,
/// those of them that keep the goal in the workspace ([`pushes_keeping_goal`]); under its
/// `push_reach`, of those, the ones that pass near the goal ([`pushes_near_goal`]); under
/// its `landing_guard`, of those, the ones whose jaws come down clear of every object
/// ([`pushes_landing_clear`]) and, given a `landing_view` (the scene rendered finer), clear
/// of the goal as it sees it ([`pushes_landing_clear_of`]; not under `landing_retreat`,
/// which moves the chosen push instead). A mask that would leave no push
/// is not applied, nor any after it: the landing guard comes last so that, where it would
/// close every push near a goal packed in on all sides, the pushes that reach the goal stay
/// open rather than pushes in the air, which change nothing.
pub fn push_region(
    obs: &Heightmaps,
    landing_view: Option<&Heightmaps>,
    goal: ObjectId,
    config: &PolicyConfig,
    push_length: f32,
) -> Vec<bool> {
    let starts = valid_push_starts(obs);
    let masks: Vec<Vec<bool>> = [
        config
            .goal_guard
            .map(|margin| pushes_keeping_goal(obs, goal, push_length, margin)),
        config
            .push_reach
            .map(|reach| pushes_near_goal(obs, goal, push_length, reach)),
        config.landing_guard.map(|margin| {
            let clear = pushes_landing_clear(obs, margin);
            match landing_view {
                // Under a retreat the finer view moves the chosen push instead.
                Some(view) if config.landing_retreat.is_none() => (clear.iter())
                    .zip(pushes_landing_clear_of(obs, view, goal, margin))
                    .map(|(&a, b)| a && b)
                    .collect(),
                _ => clear,
            }
        }),
    ]
    .into_iter()
    .flatten()
    .collect();
    if masks.is_empty() {
        return starts;
    }
    narrowed_in_turn(starts.repeat(ROTATIONS as usize), masks)
}
