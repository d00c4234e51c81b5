//! The scene's materials as its engine, Bullet 2.83, takes them: each collider's friction,
//! combined in a contact as Bullet combines them (the product), no restitution; and the test
//! objects as the authors' importer leaves them.
//!
//! The objects are not in the scene file: its `remoteApiCommandServer` script imports each
//! mesh (`sim.importShape`), makes it dynamic and respondable, and leaves its mass and
//! material at CoppeliaSim 4.0's defaults (CoppeliaRobotics/coppeliaSimLib at 64440ef:
//! `CGeomWrap::CGeomWrap` sets `_mass=1.0f`; `CDynMaterialObject::_setDefaultParameters` a
//! Bullet 2.83 friction of 0.71, restitution 0). Bullet multiplies two bodies' frictions in
//! a contact (bullet3 2.83.7, `btManifoldResult::calculateCombinedFriction`), and
//! CoppeliaSim's plugin sets each body's friction from its material (simExtDynamics,
//! `CRigidBodyDyn_bullet283`).
//!
//! One default is not taken: the importer's moments of inertia (`setDefaultInertiaParams`,
//! 0.001 kg m^2 at 1 kg, about 2.4 times a 5 cm cube's). With them, blocks set down touching
//! creep apart by a centimetre while they settle here (the arrangement tests); each object
//! keeps its own shape's moments at its 1 kg.

use rapier3d::prelude::*;

/// An object's mass (kg), whatever its shape.
pub(crate) const OBJECT_MASS: f32 = 1.0;
/// The objects' friction (the default material) and the floor's (`ResizableFloor_5_25_element`).
pub(crate) const OBJECT_FRICTION: f32 = 0.71;
pub(crate) const TABLE_FRICTION: f32 = 0.5;

/// A collider with this friction, combined as Bullet combines it, and no restitution.
pub(crate) fn bullet(collider: ColliderBuilder, friction: f32) -> ColliderBuilder {
    collider
        .friction(friction)
        .friction_combine_rule(CoefficientCombineRule::Multiply)
        .restitution(0.0)
}
