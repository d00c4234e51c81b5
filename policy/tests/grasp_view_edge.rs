//! The view edge guard against the physics it predicts: every object of the catalogue, its
//! centre 10 mm past the workspace's left side, grasped at its visible middle, leaves the
//! camera's view far more often when the jaws close along that side than across it; the
//! guard closes the first and leaves the second open; at a corner only the diagonals stay
//! open, and a goal clear of every side keeps every grasp; the policy under the guard
//! passes over a closed grasp however high its Q.

mod common;
mod grasp_choice;
mod lone;

use common::cube;
use grasp_choice::chosen_grasp;
use lone::lone;
use sim::rapier3d::prelude::{Pose, Rotation, Vector};
use sim::workspace::{CENTRE, SIDE, X_MIN};
use sim::{
    Action, Camera, Heightmaps, ObjectId, Primitive, ROTATIONS, ShapeKind, SimConfig, Tabletop,
};

use policy::{PolicyConfig, grasp_region, grasps_across_view_edge};

const GOAL: ObjectId = 1;

/// Whether each rotation is open at every pixel (and closed at every pixel otherwise).
fn open_rotations(obs: &Heightmaps, goal: ObjectId) -> Vec<u8> {
    let mask = grasps_across_view_edge(obs, goal);
    let per_rotation = obs.side() * obs.side();
    (0..ROTATIONS)
        .filter(|&r| {
            let rotation = &mask[r as usize * per_rotation..][..per_rotation];
            assert!(rotation.iter().all(|&m| m == rotation[0]), "rotation {r}");
            rotation[0]
        })
        .collect()
}

/// `kind` turned `yaw` about the vertical, its centre `past` metres beyond the left side,
/// settled; what the camera sees at the tests' 4 mm pixels.
fn at_left_side(kind: ShapeKind, yaw: f32, past: f32) -> (Tabletop, Heightmaps) {
    let pose = Pose::from_parts(
        Vector::new(X_MIN - past, CENTRE[1], 0.03),
        Rotation::from_rotation_z(yaw),
    );
    lone(&SimConfig::with_pixel_size(0.004), GOAL, kind, pose)
}

/// A grasp at `rotation` at the pixel of the goal's grasp region (20 mm margin) nearest
/// its middle.
fn grasp_in_the_middle(obs: &Heightmaps, rotation: u8) -> Action {
    let side = obs.side();
    let region = grasp_region(obs, GOAL, 0.02);
    let pixels: Vec<usize> = (0..side * side).filter(|&i| region[i]).collect();
    let n = pixels.len() as f32;
    let (row, col) = pixels.iter().fold((0.0, 0.0), |(r, c), &i| {
        (r + (i / side) as f32 / n, c + (i % side) as f32 / n)
    });
    let distance = |i: usize| ((i / side) as f32 - row).powi(2) + ((i % side) as f32 - col).powi(2);
    let at = pixels
        .into_iter()
        .min_by(|&a, &b| distance(a).total_cmp(&distance(b)))
        .expect("the goal is in view");
    Action {
        primitive: Primitive::Grasp,
        rotation,
        row: at / side,
        col: at % side,
    }
}

#[test]
fn grasps_closing_along_the_side_knock_the_goal_out_of_view_and_the_guard_closes_them() {
    // Rotation 0 closes along x, across the left side; rotation 4 along y, along it.
    let (mut grasps, mut lost) = ([0; 2], [0; 2]);
    for kind in ShapeKind::ALL {
        for yaw in [0.0, 0.4, 0.785] {
            for (k, rotation) in [0, 4].into_iter().enumerate() {
                let (mut tabletop, obs) = at_left_side(kind, yaw, 0.01);
                if tabletop.object(GOAL).is_none() {
                    continue; // it toppled out of view as it settled
                }
                grasps[k] += 1;
                assert_eq!(
                    open_rotations(&obs, GOAL),
                    [0, 1, 2, 6, 7, 8, 9, 10, 14, 15]
                );
                let outcome = tabletop.act(&grasp_in_the_middle(&obs, rotation), &obs);
                let gone = outcome.unwrap().grasped.is_none() && tabletop.object(GOAL).is_none();
                lost[k] += usize::from(gone);
            }
        }
    }
    // Measured: 0 and 11 of the 22 grasps of objects still in view after settling.
    assert!(grasps.iter().all(|&n| n >= 20), "grasps made: {grasps:?}");
    assert!(lost[0] <= 3 && lost[1] >= 8, "lost across, along: {lost:?}");
}

#[test]
fn at_a_corner_only_the_diagonals_stay_open_and_clear_of_the_sides_every_rotation_does() {
    let corner = SIDE / 2.0 - 0.01;
    for (dx, dy, open) in [
        (-corner, corner, vec![2, 6, 10, 14]),
        (0.0, 0.0, (0..ROTATIONS).collect()),
    ] {
        let mut tabletop = Tabletop::new(&SimConfig::with_pixel_size(0.004)).unwrap();
        cube(&mut tabletop, GOAL, dx, dy, 0.025);
        let obs = Camera::new(tabletop.grid()).render(&tabletop);
        assert_eq!(open_rotations(&obs, GOAL), open, "cube at ({dx}, {dy})");
    }
}

#[test]
fn under_the_view_edge_guard_the_policy_passes_over_a_grasp_along_the_side() {
    let (_, obs) = at_left_side(ShapeKind::Cube, 0.0, 0.01);
    let along = grasp_in_the_middle(&obs, 4);
    let push_length = SimConfig::default().push_length;
    let chosen = |policy: &PolicyConfig| chosen_grasp(&obs, GOAL, &along, policy, push_length);
    assert_eq!(chosen(&PolicyConfig::default()).action, along);
    let guarded = PolicyConfig {
        view_edge_guard: true,
        ..PolicyConfig::default()
    };
    let action = chosen(&guarded).action;
    assert_eq!(action.primitive, Primitive::Grasp);
    assert!(
        grasps_across_view_edge(&obs, GOAL)
            [(action.rotation as usize * obs.side() + action.row) * obs.side() + action.col]
    );
}
