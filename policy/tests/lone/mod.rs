//! Helper of the grasp guards' simulator tests: one object alone on the table.

use sim::rapier3d::prelude::Pose;
use sim::{Camera, Heightmaps, ObjectId, ShapeKind, SimConfig, Tabletop};

/// `kind` alone at `pose` as object `id`, settled; the scene and what the camera sees.
pub fn lone(
    config: &SimConfig,
    id: ObjectId,
    kind: ShapeKind,
    pose: Pose,
) -> (Tabletop, Heightmaps) {
    let mut tabletop = Tabletop::new(config).unwrap();
    tabletop
        .add_object(id, kind, [118, 183, 178], pose)
        .unwrap();
    tabletop.settle();
    let obs = Camera::new(tabletop.grid()).render(&tabletop);
    (tabletop, obs)
}
