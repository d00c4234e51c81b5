//! The landing guards against the physics they predict: a push whose closed jaws come down
//! on an object is closed, and in the simulator such a push does throw the object; one that
//! comes down clear of it is open; the policy under the guard passes over a closed push
//! however high its Q; where the guard would close every push near the goal, those stay
//! open rather than the pushes in the air. A grasp whose open pads would come down on a
//! neighbour's top is closed, and in the simulator it picks nothing; turned a quarter it is
//! open and picks the goal; the policy under the grasp guard passes over a closed grasp.
//! Seen finer, a push whose jaws come down on the goal's corner between pixel centres is
//! closed, which the observation's pixels miss, and the policy passes over it, or under a
//! retreat starts it a pixel back.

mod closed_push;
mod common;
mod grasp_choice;
mod masks;

use closed_push::passes_over;
use grasp_choice::chosen_grasp;
use masks::{chosen, cubes, index, push};
use sim::rapier3d::prelude::{Pose, Rotation, Vector};
use sim::workspace::CENTRE;
use sim::{
    Action, Camera, Heightmaps, Jaws, ObjectId, Primitive, ROTATIONS, ShapeKind, SimConfig,
    Tabletop, jaws_parts,
};

use policy::{
    PolicyConfig, grasp_choices, grasps_landing_clear, push_region, pushes_landing_clear,
    pushes_landing_clear_of, pushes_near_goal, valid_push_starts,
};

const GOAL: ObjectId = 1;
/// Rotation 0 pushes towards +x, rotation 12 towards -y.
const TOWARDS_X: u8 = 0;
const TOWARDS_MINUS_Y: u8 = 12;

/// Whether a push towards +x from `behind` metres before the 5 cm cube at the workspace
/// centre, `aside` metres off its line, lowers the jaws (widened by `margin`) clear of it.
fn clear(obs: &Heightmaps, behind: f32, aside: f32, margin: f32) -> bool {
    let action = push(obs, TOWARDS_X, -behind, aside);
    pushes_landing_clear(obs, margin)[index(obs, &action)]
}

#[test]
fn jaws_coming_down_on_a_cube_close_the_push_and_clear_of_it_leave_it_open() {
    let (_, obs, _) = cubes(&[(GOAL, 0.0, 0.0)]);
    // The cube's face is 25 mm from its centre; the knuckles reach 20.5 mm ahead of the start.
    assert!(!clear(&obs, 0.035, 0.0, 0.0));
    assert!(clear(&obs, 0.07, 0.0, 0.0));
    // Beside the cube: the jaws are 20 mm wide across the push.
    assert!(clear(&obs, 0.0, 0.05, 0.0));
    // A margin closes a start the bare jaws would clear.
    assert!(clear(&obs, 0.044, 0.0, 0.0));
    assert!(!clear(&obs, 0.044, 0.0, 0.004));
}

/// The push along +x the corner tests make, from a pixel near the workspace's centre.
const ONTO_THE_CORNER: Action = Action {
    primitive: Primitive::Push,
    rotation: TOWARDS_X,
    row: 56,
    col: 40,
};

/// A cube turned 45 degrees, its corner towards [`ONTO_THE_CORNER`], `inside` metres inside
/// the closed jaws' front, 2 mm off the row of pixel centres (halfway between two): what the
/// camera sees, and that seen five times finer.
fn corner_under_the_jaws(inside: f32) -> (Heightmaps, Heightmaps) {
    let config = SimConfig::with_pixel_size(0.004);
    let mut tabletop = Tabletop::new(&config).unwrap();
    let [x, y] = (tabletop.grid()).pixel_centre(ONTO_THE_CORNER.row, ONTO_THE_CORNER.col);
    let front = jaws_parts(Jaws::Closed)
        .iter()
        .map(|p| p.along[1])
        .fold(f32::MIN, f32::max);
    let to_corner = 0.025 * std::f32::consts::SQRT_2;
    let pose = Pose::from_parts(
        Vector::new(x + front - inside + to_corner, y + 0.002, 0.025),
        Rotation::from_rotation_z(std::f32::consts::FRAC_PI_4),
    );
    tabletop
        .add_object(GOAL, ShapeKind::Cube, [200, 50, 50], pose)
        .unwrap();
    let obs = Camera::new(tabletop.grid()).render(&tabletop);
    let view = Camera::new(tabletop.grid().finer(5).unwrap()).render(&tabletop);
    (obs, view)
}

#[test]
fn a_finer_view_closes_a_push_whose_jaws_come_down_on_a_corner_between_pixel_centres() {
    for inside in [0.001, 0.0015, 0.002] {
        let (obs, view) = corner_under_the_jaws(inside);
        let i = index(&obs, &ONTO_THE_CORNER);
        assert!(pushes_landing_clear(&obs, 0.0)[i], "{inside}: seen at 4 mm");
        assert!(
            !pushes_landing_clear_of(&obs, &view, GOAL, 0.0)[i],
            "{inside}: seen finer"
        );
    }
    // A millimetre ahead of the jaws, the corner closes nothing either way.
    let (obs, view) = corner_under_the_jaws(-0.001);
    let i = index(&obs, &ONTO_THE_CORNER);
    assert!(pushes_landing_clear(&obs, 0.0)[i]);
    assert!(pushes_landing_clear_of(&obs, &view, GOAL, 0.0)[i]);
}

#[test]
fn under_a_finer_view_the_policy_passes_over_a_push_onto_the_goal_s_corner() {
    let (obs, view) = corner_under_the_jaws(0.0015);
    let guarded = PolicyConfig {
        landing_guard: Some(0.0),
        landing_subpixels: 5,
        ..PolicyConfig::default()
    };
    let push_length = SimConfig::default().push_length;
    passes_over(
        &obs,
        Some(&view),
        GOAL,
        push_length,
        &ONTO_THE_CORNER,
        &guarded,
    );
}

#[test]
fn under_a_retreat_the_push_onto_the_goal_s_corner_starts_a_pixel_back() {
    let (obs, view) = corner_under_the_jaws(0.0015);
    let retreating = PolicyConfig {
        landing_guard: Some(0.0),
        landing_subpixels: 5,
        landing_retreat: Some(0.012),
        ..PolicyConfig::default()
    };
    // Rotation 0 pushes towards +x: a pixel back is a column lower.
    let back = Action {
        col: ONTO_THE_CORNER.col - 1,
        ..ONTO_THE_CORNER
    };
    assert_eq!(chosen_push(&obs, Some(&view), &retreating), back);
    assert!(pushes_landing_clear_of(&obs, &view, GOAL, 0.0)[index(&obs, &back)]);
    // Without the finer view nothing is seen to move the push.
    let coarse = PolicyConfig {
        landing_retreat: None,
        landing_subpixels: 1,
        ..retreating
    };
    assert_eq!(chosen_push(&obs, None, &coarse), ONTO_THE_CORNER);
    // A push clear of the goal is made as chosen.
    let (obs, view) = corner_under_the_jaws(-0.001);
    assert_eq!(chosen_push(&obs, Some(&view), &retreating), ONTO_THE_CORNER);
}

/// The policy's greedy push towards the corner scene's peak, [`ONTO_THE_CORNER`].
fn chosen_push(obs: &Heightmaps, view: Option<&Heightmaps>, policy: &PolicyConfig) -> Action {
    let push_length = SimConfig::default().push_length;
    chosen(
        obs,
        view,
        GOAL,
        push_length,
        &ONTO_THE_CORNER,
        policy,
        0.0,
        0,
    )
}

#[test]
fn a_finer_view_keeps_every_verdict_far_from_the_objects() {
    // Judging the goal alone, both views agree wherever the jaws come down more than a pixel
    // from its outline: they differ on under a tenth of the pushes the coarse view closes.
    let (tabletop, obs, _) = cubes(&[(GOAL, 0.0, 0.0), (2, 0.08, 0.03)]);
    let view = Camera::new(tabletop.grid().finer(3).unwrap()).render(&tabletop);
    let coarse = pushes_landing_clear_of(&obs, &obs, GOAL, 0.0);
    let fine = pushes_landing_clear_of(&obs, &view, GOAL, 0.0);
    let differ = coarse.iter().zip(&fine).filter(|(c, f)| c != f).count();
    let closed = coarse.iter().filter(|&&c| !c).count();
    assert!(differ * 10 < closed, "{differ} of {closed}");
}

#[test]
fn the_bare_table_closes_nothing() {
    let (_, obs, _) = cubes(&[]);
    assert!(pushes_landing_clear(&obs, 0.004).iter().all(|&c| c));
}

#[test]
fn a_push_the_guard_closes_does_throw_the_object_and_one_it_leaves_open_does_not() {
    // A tall block lying along y; pushes towards -y from beyond its end. From 65-68 mm the
    // closed jaws come down on that end, from 80 mm beside it.
    for (offset, closed) in [(0.065, true), (0.0675, true), (0.08, false)] {
        let config = SimConfig::with_pixel_size(0.004);
        let mut tabletop = Tabletop::new(&config).unwrap();
        let lying = Pose::from_parts(
            Vector::new(CENTRE[0], CENTRE[1], 0.025),
            Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2),
        );
        tabletop
            .add_object(GOAL, ShapeKind::TallBlock, [200, 50, 50], lying)
            .unwrap();
        tabletop.settle();
        let obs = Camera::new(tabletop.grid()).render(&tabletop);
        let before = tabletop.object(GOAL).unwrap().pose.translation;
        let action = push(&obs, TOWARDS_MINUS_Y, 0.0, before.y - CENTRE[1] + offset);
        assert_eq!(
            pushes_landing_clear(&obs, 0.0)[index(&obs, &action)],
            !closed,
            "offset {offset}"
        );
        tabletop.act(&action, &obs).unwrap();
        // Pushed, the block goes about as far as the push (13 cm); thrown, it leaves the view.
        let moved = tabletop
            .object(GOAL)
            .map(|o| (o.pose.translation - before).truncate().length());
        match closed {
            true => assert_eq!(moved, None, "offset {offset}: not thrown"),
            false => assert!(
                moved.is_some_and(|m| m < 0.15),
                "offset {offset}: {moved:?}"
            ),
        }
    }
}

#[test]
fn under_the_guard_the_policy_passes_over_a_closed_push() {
    let (_, obs, config) = cubes(&[(GOAL, 0.0, 0.0)]);
    let closed = push(&obs, TOWARDS_X, -0.035, 0.0);
    let guarded = PolicyConfig {
        landing_guard: Some(0.0),
        ..PolicyConfig::default()
    };
    passes_over(&obs, None, GOAL, config.push_length, &closed, &guarded);
}

#[test]
fn where_the_guard_would_close_every_push_near_the_goal_those_pushes_stay_open() {
    // A margin this wide leaves open only starts far out in the workspace, none within the
    // reach of the goal.
    const WIDE: f32 = 0.15;
    const REACH: f32 = 0.04;
    let (_, obs, config) = cubes(&[(GOAL, 0.0, 0.0)]);
    let near = pushes_near_goal(&obs, GOAL, config.push_length, REACH);
    let clear = pushes_landing_clear(&obs, WIDE);
    let both =
        |a: &[bool], b: &[bool]| -> Vec<bool> { a.iter().zip(b).map(|(&a, &b)| a && b).collect() };
    assert!(clear.contains(&true));
    assert!(!both(&near, &clear).contains(&true));
    let region = |policy: &PolicyConfig| push_region(&obs, None, GOAL, policy, config.push_length);
    let guarded = PolicyConfig {
        landing_guard: Some(WIDE),
        ..PolicyConfig::default()
    };
    assert!(!both(&region(&guarded), &near).contains(&true));
    let reaching_and_guarded = PolicyConfig {
        push_reach: Some(REACH),
        ..guarded
    };
    let starts = valid_push_starts(&obs).repeat(ROTATIONS as usize);
    assert_eq!(region(&reaching_and_guarded), both(&starts, &near));
}

/// A neighbour cube 10 mm beside the goal cube along x (their centres 60 mm apart).
const NEIGHBOUR: ObjectId = 2;
const NEIGHBOUR_AT: f32 = 0.06;
/// Rotation 4 turns the jaw axis from x to y.
const JAWS_ALONG_Y: u8 = 4;

/// Every pixel, for a guard to judge.
fn everywhere(obs: &Heightmaps) -> Vec<bool> {
    vec![true; obs.side() * obs.side()]
}

/// A grasp at `rotation` at the goal cube's centre (the workspace centre).
fn grasp_at_goal(obs: &Heightmaps, rotation: u8) -> Action {
    Action {
        primitive: Primitive::Grasp,
        ..push(obs, rotation, 0.0, 0.0)
    }
}

#[test]
fn open_jaws_coming_down_on_a_neighbour_close_the_grasp_and_turned_clear_of_it_leave_it_open() {
    let (_, obs, _) = cubes(&[(GOAL, 0.0, 0.0), (NEIGHBOUR, NEIGHBOUR_AT, 0.0)]);
    let clear = grasps_landing_clear(&obs, 0.0, &everywhere(&obs));
    // The open pads stand 50 mm either side of the tool point, their ends 35.5 mm above the
    // table over a 50 mm cube: along x one comes down on the neighbour's top.
    assert!(!clear[index(&obs, &grasp_at_goal(&obs, 0))]);
    assert!(clear[index(&obs, &grasp_at_goal(&obs, JAWS_ALONG_Y))]);
    // Alone, the goal sits between the pads either way.
    let (_, alone, _) = cubes(&[(GOAL, 0.0, 0.0)]);
    let clear = grasps_landing_clear(&alone, 0.0, &everywhere(&alone));
    assert!(clear[index(&alone, &grasp_at_goal(&alone, 0))]);
    assert!(clear[index(&alone, &grasp_at_goal(&alone, JAWS_ALONG_Y))]);
}

#[test]
fn under_the_grasp_guard_the_policy_passes_over_a_closed_grasp() {
    let (_, obs, config) = cubes(&[(GOAL, 0.0, 0.0), (NEIGHBOUR, NEIGHBOUR_AT, 0.0)]);
    let closed = grasp_at_goal(&obs, 0);
    let chosen =
        |policy: &PolicyConfig| chosen_grasp(&obs, GOAL, &closed, policy, config.push_length);
    assert_eq!(chosen(&PolicyConfig::default()).action, closed);
    let guarded = PolicyConfig {
        grasp_landing_guard: Some(0.0),
        ..PolicyConfig::default()
    };
    let decision = chosen(&guarded);
    assert_eq!(decision.action.primitive, Primitive::Grasp);
    assert_ne!(decision.action, closed);
    assert_eq!(decision.goal_grasp_q, 2.0, "read over the open grasps only");
    let region = grasp_choices(&obs, GOAL, &guarded, &[]);
    assert!(region[index(&obs, &decision.action)]);
    assert!(!region[index(&obs, &closed)]);
}

#[test]
fn where_the_grasp_guard_would_close_every_grasp_of_the_goal_they_stay_open() {
    let (_, obs, _) = cubes(&[(GOAL, 0.0, 0.0), (NEIGHBOUR, NEIGHBOUR_AT, 0.0)]);
    // A margin this wide lands the jaws on something wherever they come down.
    let guarded = PolicyConfig {
        grasp_landing_guard: Some(0.2),
        ..PolicyConfig::default()
    };
    let unguarded = grasp_choices(&obs, GOAL, &PolicyConfig::default(), &[]);
    assert_eq!(
        grasp_choices(&obs, GOAL, &guarded, &[]),
        unguarded.repeat(ROTATIONS as usize)
    );
}

#[test]
fn a_grasp_the_guard_closes_does_pick_nothing_and_the_one_it_leaves_open_picks_the_goal() {
    for (rotation, closed) in [(0, true), (JAWS_ALONG_Y, false)] {
        let (mut tabletop, obs, _) = cubes(&[(GOAL, 0.0, 0.0), (NEIGHBOUR, NEIGHBOUR_AT, 0.0)]);
        let grasp = grasp_at_goal(&obs, rotation);
        assert_eq!(
            grasps_landing_clear(&obs, 0.0, &everywhere(&obs))[index(&obs, &grasp)],
            !closed
        );
        let outcome = tabletop.act(&grasp, &obs).unwrap();
        // Held up on the neighbour's top, the pads close above the goal.
        let want = if closed { None } else { Some(GOAL) };
        assert_eq!(outcome.grasped, want, "rotation {rotation}");
    }
}
