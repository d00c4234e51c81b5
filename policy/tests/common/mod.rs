//! Scene helpers shared by the actor's tests.

use sim::rapier3d::prelude::{Pose, Vector};
use sim::workspace::CENTRE;
use sim::{ObjectId, SLOT_COLOURS, ShapeKind, Tabletop};

/// Adds a cube offset (dx, dy) from the workspace centre with its centre at height z.
pub fn cube(tabletop: &mut Tabletop, id: ObjectId, dx: f32, dy: f32, z: f32) {
    let at = Vector::new(CENTRE[0] + dx, CENTRE[1] + dy, z);
    tabletop
        .add_object(
            id,
            ShapeKind::Cube,
            SLOT_COLOURS[id as usize % 10],
            Pose::from_translation(at),
        )
        .unwrap();
}
