//! The goal guard against the physics it predicts: pushes it closes do carry the goal out of
//! the workspace in the simulator, pushes it leaves open do not, and the policy under the
//! guard passes over a closed push however high its Q.

mod closed_push;
mod common;
mod masks;

use closed_push::passes_over;
use masks::{cubes, index, push};
use sim::workspace::{CENTRE, SIDE};
use sim::{Action, Heightmaps, ObjectId, ROTATIONS, SimConfig, Tabletop};

use policy::{PolicyConfig, pushes_keeping_goal};

const GOAL: ObjectId = 1;
/// Rotation 0 pushes towards +x, rotation 8 towards -x.
const TOWARDS_EDGE: u8 = 0;
const AWAY_FROM_EDGE: u8 = 8;
const MARGIN: f32 = 0.02;

/// A 5 cm goal cube whose centre is `from_edge` metres from the workspace's +x edge.
fn goal_near_edge(from_edge: f32) -> (Tabletop, Heightmaps, SimConfig) {
    cubes(&[(GOAL, SIDE / 2.0 - from_edge, 0.0)])
}

fn keeps(obs: &Heightmaps, config: &SimConfig, action: &Action) -> bool {
    pushes_keeping_goal(obs, GOAL, config.push_length, MARGIN)[index(obs, action)]
}

/// Executes `action` and says whether the goal is still on the table.
fn goal_stays(mut tabletop: Tabletop, obs: &Heightmaps, action: &Action) -> bool {
    tabletop.act(action, obs).unwrap();
    tabletop.object(GOAL).is_some()
}

#[test]
fn a_push_carrying_the_goal_over_the_edge_is_closed_and_does_lose_it() {
    let (tabletop, obs, config) = goal_near_edge(0.07);
    // 3 cm behind the cube's far-from-edge face, pushing towards the edge.
    let action = push(&obs, TOWARDS_EDGE, SIDE / 2.0 - 0.07 - 0.055, 0.0);
    assert!(!keeps(&obs, &config, &action));
    assert!(!goal_stays(tabletop, &obs, &action));
}

#[test]
fn pushes_away_from_the_edge_or_past_the_goal_stay_open_and_keep_it() {
    let (tabletop, obs, config) = goal_near_edge(0.07);
    let behind = SIDE / 2.0 - 0.07 - 0.055;
    let away = push(&obs, AWAY_FROM_EDGE, behind, 0.0);
    // 6 cm to the side: the 5 cm cube and the 2.4 cm tool do not meet.
    let beside = push(&obs, TOWARDS_EDGE, behind, 0.06);
    for action in [away, beside] {
        assert!(keeps(&obs, &config, &action), "{action:?}");
        assert!(goal_stays(tabletop.replica(), &obs, &action), "{action:?}");
    }
}

#[test]
fn a_push_that_moves_the_goal_but_not_out_stays_open() {
    let (tabletop, obs, config) = goal_near_edge(SIDE / 2.0);
    let action = push(&obs, TOWARDS_EDGE, -0.055, 0.0);
    assert!(keeps(&obs, &config, &action));
    let mut moved = tabletop.replica();
    moved.act(&action, &obs).unwrap();
    let x = moved
        .object(GOAL)
        .expect("the goal stays")
        .pose
        .translation
        .x;
    assert!(x > CENTRE[0] + 0.05, "the push met the goal: x {x}");
}

#[test]
fn an_unseen_goal_closes_nothing() {
    let (_, obs, config) = goal_near_edge(0.07);
    let guard = pushes_keeping_goal(&obs, 7, config.push_length, MARGIN);
    assert_eq!(guard.len(), ROTATIONS as usize * obs.side() * obs.side());
    assert!(guard.iter().all(|&k| k));
}

#[test]
fn under_the_guard_the_policy_passes_over_a_closed_push() {
    let (_, obs, config) = goal_near_edge(0.07);
    let closed = push(&obs, TOWARDS_EDGE, SIDE / 2.0 - 0.07 - 0.055, 0.0);
    let guarded = PolicyConfig {
        goal_guard: Some(MARGIN),
        ..PolicyConfig::default()
    };
    passes_over(&obs, None, GOAL, config.push_length, &closed, &guarded);
}
