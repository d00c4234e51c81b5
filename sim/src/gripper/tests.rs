use super::*;
use crate::{SimConfig, Tabletop};

/// Where the pads' lower ends are now, above the tool point.
fn pad_end_now(world: &PhysicsWorld, gripper: &Gripper) -> f32 {
    let palm = world.bodies[gripper.palm].position();
    let finger = world.bodies[gripper.sides[0].finger].translation();
    palm.inverse_transform_point(finger).z + pad_end_on_finger()
}

/// Drives the jaws to a limit for half a second, the palm held still, and returns the gap
/// and the height of the pads' ends then.
fn drive(tabletop: &mut Tabletop, tool: Pose, jaws: Jaws) -> (f32, f32) {
    tabletop.gripper.command(&mut tabletop.world, jaws);
    for _ in 0..120 {
        tabletop.gripper.drive_to(&mut tabletop.world, tool);
        tabletop.step();
    }
    let gripper = &tabletop.gripper;
    (
        gripper.opening(&tabletop.world),
        pad_end_now(&tabletop.world, gripper),
    )
}

#[test]
fn the_fingers_sweep_down_on_their_arcs_as_the_jaws_close() {
    // The scene's figures: the pads' ends 15.5 mm above the tool point fully open, 22.8
    // mm below it closed (at the arc model's stop, 1.5 mm apart: 22.6 mm).
    let open_end = 0.0155;
    assert!((pad_end_height(Jaws::Closed) + 0.0226).abs() < 5e-4);
    assert!((pad_end_height(Jaws::Open) - open_end).abs() < 5e-4);

    let mut tabletop = Tabletop::new(&SimConfig::default()).unwrap();
    let tool = Pose::from_translation(Vector::new(-0.5, 0.0, 0.5));
    tabletop
        .gripper
        .place(&mut tabletop.world, tool, Jaws::Open);
    for (jaws, gap, end) in [
        (Jaws::Closed, CLOSED_GAP, pad_end_height(Jaws::Closed)),
        (Jaws::Open, OPEN_GAP, open_end),
        (Jaws::Closed, CLOSED_GAP, pad_end_height(Jaws::Closed)),
    ] {
        let (gap_now, end_now) = drive(&mut tabletop, tool, jaws);
        assert!((gap_now - gap).abs() < 5e-4, "{jaws:?}: gap {gap_now}");
        assert!(
            (end_now - end).abs() < 1e-3,
            "{jaws:?}: the linkage holds the pads on their arcs: ends at {end_now}"
        );
    }
    assert!(
        tabletop.gripper.opening(&tabletop.world) < JAWS_CLOSED_GAP,
        "closed on nothing reads as closed"
    );
}
