//! The squeeze guard against the physics it predicts: a roof standing on end, grasped across
//! faces that slope the same way, shoots out of the jaws in the simulator, and the guard
//! closes those grasps; the grasps it leaves open pick the roof; a cube grasped across its
//! corners turns into the jaws, and the guard leaves every such grasp open; the policy under
//! the guard passes over a closed grasp however high its Q.

mod grasp_choice;
mod lone;

use grasp_choice::chosen_grasp;
use lone::lone;
use sim::rapier3d::prelude::{Pose, Rotation, Vector};
use sim::workspace::CENTRE;
use sim::{Action, Heightmaps, ObjectId, Primitive, ROTATIONS, ShapeKind, SimConfig, Tabletop};

use policy::{PolicyConfig, grasps_holding_goal};

const GOAL: ObjectId = 1;
/// The pads' friction with an object: 0.5 times 0.71, as Bullet combines them.
const FRICTION: f32 = 0.355;

/// `kind` alone at the workspace centre, turned by `rotation`, settled; what the camera sees.
fn centred(kind: ShapeKind, rotation: Rotation) -> (Tabletop, Heightmaps) {
    let pose = Pose::from_parts(Vector::new(CENTRE[0], CENTRE[1], 0.026), rotation);
    lone(&SimConfig::default(), GOAL, kind, pose)
}

/// challenging-02's goal: a roof standing on end, its pentagon seen from above.
fn standing_roof() -> (Tabletop, Heightmaps) {
    let rotation = Rotation::from_rotation_x(1.5709037)
        * Rotation::from_rotation_y(0.40463126)
        * Rotation::from_rotation_z(3.1402535);
    centred(ShapeKind::Roof, rotation)
}

/// A grasp at `rotation` at the goal's centre.
fn grasp_at_centre(tabletop: &Tabletop, rotation: u8) -> Action {
    let at = tabletop.object(GOAL).unwrap().pose.translation;
    let (row, col) = tabletop.grid().pixel_of(at.x, at.y).unwrap();
    Action {
        primitive: Primitive::Grasp,
        rotation,
        row,
        col,
    }
}

fn index(obs: &Heightmaps, action: &Action) -> usize {
    let side = obs.side();
    (action.rotation as usize * side + action.row) * side + action.col
}

#[test]
fn a_grasp_the_guard_closes_shoots_the_roof_out_and_one_it_leaves_open_picks_it() {
    for (rotation, closed) in [(0, true), (1, false), (3, true)] {
        let (mut tabletop, obs) = standing_roof();
        let grasp = grasp_at_centre(&tabletop, rotation);
        assert_eq!(
            grasps_holding_goal(&obs, GOAL, FRICTION)[index(&obs, &grasp)],
            !closed,
            "rotation {rotation}"
        );
        let before = tabletop.object(GOAL).unwrap().pose.translation;
        let outcome = tabletop.act(&grasp, &obs).unwrap();
        if closed {
            let moved = tabletop
                .object(GOAL)
                .map(|o| (o.pose.translation - before).truncate().length());
            assert!(
                outcome.grasped.is_none() && moved.is_some_and(|m| m > 0.05),
                "rotation {rotation}: {outcome:?}, moved {moved:?}"
            );
        } else {
            assert_eq!(outcome.grasped, Some(GOAL), "rotation {rotation}");
        }
    }
}

#[test]
fn a_cube_grasped_across_its_corners_stays_open_at_every_rotation() {
    let (tabletop, obs) = centred(ShapeKind::Cube, Rotation::from_rotation_z(0.785));
    let holding = grasps_holding_goal(&obs, GOAL, FRICTION);
    for rotation in 0..ROTATIONS {
        assert!(
            holding[index(&obs, &grasp_at_centre(&tabletop, rotation))],
            "rotation {rotation}"
        );
    }
}

#[test]
fn under_the_squeeze_guard_the_policy_passes_over_a_closed_grasp() {
    let (tabletop, obs) = standing_roof();
    let closed = grasp_at_centre(&tabletop, 0);
    let push_length = SimConfig::default().push_length;
    let chosen = |policy: &PolicyConfig| chosen_grasp(&obs, GOAL, &closed, policy, push_length);
    assert_eq!(chosen(&PolicyConfig::default()).action, closed);
    let guarded = PolicyConfig {
        squeeze_guard: Some(FRICTION),
        ..PolicyConfig::default()
    };
    let action = chosen(&guarded).action;
    assert_eq!(action.primitive, Primitive::Grasp);
    assert!(grasps_holding_goal(&obs, GOAL, FRICTION)[index(&obs, &action)]);
}
