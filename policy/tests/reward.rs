//! The grasp and push rewards, on hand-built change reports and on real renders.

mod common;

use common::cube;
use policy::{PUSH_REWARD, Q_IMPROVEMENT, grasp_reward, push_reward};
use sim::measure::{ChangeReport, detect_change};
use sim::{Camera, SimConfig, Tabletop};

#[test]
fn only_the_goal_object_earns_a_grasp_reward() {
    assert_eq!(grasp_reward(Some(3), 3), 1.0);
    assert_eq!(grasp_reward(Some(4), 3), 0.0);
    assert_eq!(grasp_reward(None, 3), 0.0);
}

fn report(detected: bool) -> ChangeReport {
    ChangeReport {
        changed_pixels: if detected { 120 } else { 3 },
        changed_pixels_needed: 50,
        occupancy_before: 0.6,
        occupancy_after: if detected { 0.3 } else { 0.6 },
        detected,
    }
}

#[test]
fn the_push_reward_has_the_papers_three_cases() {
    assert_eq!((PUSH_REWARD, Q_IMPROVEMENT), (0.5, 0.1));
    // Change detected and the goal's grasp Q rose by more than 0.1.
    assert_eq!(push_reward(1.0, 1.3, &report(true)), 0.5);
    // No change: -0.5 whatever the grasp Q did.
    assert_eq!(push_reward(1.0, 1.3, &report(false)), -0.5);
    assert_eq!(push_reward(1.0, 0.2, &report(false)), -0.5);
    // A change that did not raise the grasp Q enough, or lowered it.
    assert_eq!(push_reward(1.0, 1.05, &report(true)), 0.0);
    assert_eq!(push_reward(1.0, 0.2, &report(true)), 0.0);
    // "More than 0.1": exactly 0.1 is not enough.
    assert_eq!(push_reward(0.0, 0.1, &report(true)), 0.0);
}

#[test]
fn clearing_the_goals_neighbours_is_rewarded_and_an_unchanged_scene_is_penalised() {
    let mut tabletop = Tabletop::new(&SimConfig::with_pixel_size(0.004)).unwrap();
    let camera = Camera::new(tabletop.grid());
    let goal = 1;
    cube(&mut tabletop, goal, 0.0, 0.0, 0.025);
    // Four neighbours 5 mm from the goal's faces, and one far away.
    let d = 0.055;
    for (id, (dx, dy)) in (2..).zip([(d, 0.0), (-d, 0.0), (0.0, d), (0.0, -d)]) {
        cube(&mut tabletop, id, dx, dy, 0.025);
    }
    cube(&mut tabletop, 6, 0.15, 0.15, 0.025);
    let before = camera.render(&tabletop);

    // The far cube leaving changes nothing around the goal.
    assert!(tabletop.remove_object(6));
    let far_only = camera.render(&tabletop);
    let unchanged = detect_change(&before, &far_only, goal);
    assert!(!unchanged.detected, "{unchanged:?}");
    assert_eq!(push_reward(1.0, 1.3, &unchanged), -0.5);
    assert_eq!(
        push_reward(1.0, 1.3, &detect_change(&before, &before, goal)),
        -0.5
    );

    for id in 2..6 {
        assert!(tabletop.remove_object(id));
    }
    let after = camera.render(&tabletop);
    let change = detect_change(&before, &after, goal);
    assert!(change.detected, "{change:?}");
    assert_eq!(push_reward(1.0, 1.3, &change), 0.5);
    assert_eq!(push_reward(1.0, 1.05, &change), 0.0);
}
