//! The push reach mask against the physics it stands for: a push it closes moves its object
//! without touching the goal's surroundings, one it leaves open beside the goal does change
//! them, and the policy under the mask neither chooses nor explores a closed push.

mod common;
mod masks;

use masks::{chosen, cubes, index, push};
use sim::measure::detect_change;
use sim::{Action, Camera, Heightmaps, ObjectId, Primitive, ROTATIONS, SimConfig, Tabletop};

use policy::{PolicyConfig, push_region, pushes_near_goal};

const GOAL: ObjectId = 1;
const NEIGHBOUR: ObjectId = 2;
/// Rotation 0 pushes towards +x.
const TOWARDS_X: u8 = 0;
const REACH: f32 = 0.04;

/// A 5 cm goal cube at the workspace centre and a 5 cm neighbour `dy` metres beside it.
fn goal_and_neighbour(dy: f32) -> (Tabletop, Heightmaps, SimConfig) {
    cubes(&[(GOAL, 0.0, 0.0), (NEIGHBOUR, 0.0, dy)])
}

fn near(obs: &Heightmaps, config: &SimConfig, action: &Action) -> bool {
    pushes_near_goal(obs, GOAL, config.push_length, REACH)[index(obs, action)]
}

/// Executes `action`; returns how far it moved the neighbour (metres) and how many pixels
/// around the goal fell (change detection's count).
fn act(mut tabletop: Tabletop, obs: &Heightmaps, action: &Action) -> (f32, usize) {
    let before = tabletop.object(NEIGHBOUR).unwrap().pose.translation;
    tabletop.act(action, obs).unwrap();
    let after = tabletop.object(NEIGHBOUR).unwrap().pose.translation;
    let seen = Camera::new(tabletop.grid()).render(&tabletop);
    (
        (after - before).length(),
        detect_change(obs, &seen, GOAL).changed_pixels,
    )
}

#[test]
fn a_push_far_from_the_goal_is_closed_and_changes_nothing_around_it() {
    let (tabletop, obs, config) = goal_and_neighbour(0.13);
    let action = push(&obs, TOWARDS_X, -0.07, 0.13);
    assert!(!near(&obs, &config, &action));
    let (moved, changed) = act(tabletop, &obs, &action);
    assert!(moved > 0.03, "the push met its object: moved {moved} m");
    assert_eq!(changed, 0);
}

#[test]
fn a_push_beside_the_goal_is_open_and_changes_its_surroundings() {
    let (tabletop, obs, config) = goal_and_neighbour(0.055);
    let action = push(&obs, TOWARDS_X, -0.07, 0.055);
    assert!(near(&obs, &config, &action));
    let (moved, changed) = act(tabletop, &obs, &action);
    assert!(moved > 0.03, "the push met its object: moved {moved} m");
    assert!(changed > 0, "nothing fell around the goal");
}

#[test]
fn the_reach_extends_across_and_along_the_band() {
    let (_, obs, config) = goal_and_neighbour(0.13);
    // Across: the goal's face at 2.5 cm, the band's half-width 1.2 cm, the reach 4 cm.
    assert!(near(&obs, &config, &push(&obs, TOWARDS_X, -0.10, -0.06)));
    assert!(!near(&obs, &config, &push(&obs, TOWARDS_X, -0.10, -0.09)));
    // Along: pushing away from the goal, starting 3.5 or 5.5 cm past its face.
    assert!(near(&obs, &config, &push(&obs, TOWARDS_X, 0.06, 0.0)));
    assert!(!near(&obs, &config, &push(&obs, TOWARDS_X, 0.08, 0.0)));
}

#[test]
fn an_unseen_goal_closes_nothing() {
    let (_, obs, config) = goal_and_neighbour(0.13);
    let mask = pushes_near_goal(&obs, 7, config.push_length, REACH);
    assert_eq!(mask.len(), ROTATIONS as usize * obs.side() * obs.side());
    assert!(mask.iter().all(|&open| open));
}

#[test]
fn under_the_reach_the_policy_neither_chooses_nor_explores_a_closed_push() {
    let (_, obs, config) = goal_and_neighbour(0.13);
    let far = push(&obs, TOWARDS_X, -0.07, 0.13);
    let chosen = |policy: &PolicyConfig, epsilon: f32, seed: u64| {
        chosen(
            &obs,
            None,
            GOAL,
            config.push_length,
            &far,
            policy,
            epsilon,
            seed,
        )
    };
    assert_eq!(chosen(&PolicyConfig::default(), 0.0, 0), far);
    let reaching = PolicyConfig {
        push_reach: Some(REACH),
        ..PolicyConfig::default()
    };
    let region = push_region(&obs, None, GOAL, &reaching, config.push_length);
    let greedy = chosen(&reaching, 0.0, 0);
    assert_eq!(greedy.primitive, Primitive::Push);
    assert!(region[index(&obs, &greedy)] && !region[index(&obs, &far)]);
    // Exploring draws only open pushes; without the mask most draws are far from the goal
    // (a fifth of this scene's pushes pass near it).
    let drawn = |policy: &PolicyConfig| {
        (0..30)
            .map(|seed| chosen(policy, 1.0, seed))
            .filter(|action| near(&obs, &config, action))
            .count()
    };
    assert_eq!(drawn(&reaching), 30);
    assert!(drawn(&PolicyConfig::default()) < 20);
}
