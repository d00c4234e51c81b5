//! The rapier world: a table, the objects on it, and the gripper.
//!
//! The table is the original's floor, a 5 m square of which the workspace (what the camera
//! sees) is a part: an object pushed past the workspace's edge rests beyond it, partly seen,
//! and leaves the scene only once the camera sees none of it, as the original ends a run
//! when the goal's outline has left the heightmap.

use std::time::{Duration, Instant};

use rapier3d::prelude::*;

use crate::catalogue::ShapeKind;
use crate::collision::{GRIPPER_GROUP, OBJECT_GROUP, TABLE_GROUP};
use crate::config::SimConfig;
use crate::error::SimError;
use crate::footprint;
use crate::gripper::Gripper;
use crate::material::{self, OBJECT_FRICTION, OBJECT_MASS, TABLE_FRICTION};
use crate::workspace::PixelGrid;

/// An object's id: 1..=255, 0 is the table in the id heightmap.
pub type ObjectId = u8;

/// The goal of goal-agnostic mode: every object is the goal (its mask covers them all), so
/// the policy grasps whichever it scores highest, until the table is clear. The table's id,
/// which is never an object's.
pub const ANY_OBJECT: ObjectId = 0;

/// Speeds below which an object counts as at rest, and for how many steps in a row.
const REST_LINEAR: f32 = 0.005;
const REST_ANGULAR: f32 = 0.05;
const REST_STEPS: u32 = 12;
/// Below this height an object has fallen off the table.
const FALLEN_Z: f32 = -0.02;
/// Half the side of the floor, centred under the world's origin: the original scene's
/// `ResizableFloor_5_25`, 5 m square.
const FLOOR_HALF_SIDE: f32 = 2.5;

#[derive(Clone)]
struct Object {
    id: ObjectId,
    kind: ShapeKind,
    colour: [u8; 3],
    body: RigidBodyHandle,
}

/// What the camera and the reports see of an object.
#[derive(Clone, Copy, Debug)]
pub struct ObjectView {
    pub id: ObjectId,
    pub kind: ShapeKind,
    pub colour: [u8; 3],
    pub pose: Pose,
}

/// How a settle went: the steps it took, whether everything came to rest within the bound,
/// and which objects left the scene (and were removed).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SettleReport {
    pub steps: u32,
    pub at_rest: bool,
    pub removed: Vec<ObjectId>,
}

/// The tabletop world. Same construction and the same calls give the same result, bit for
/// bit, on the same build (rapier runs single-threaded here).
pub struct Tabletop {
    config: SimConfig,
    grid: PixelGrid,
    pub(crate) world: PhysicsWorld,
    objects: Vec<Object>,
    pub(crate) gripper: Gripper,
    physics_steps: u64,
    physics_time: Duration,
}

impl Tabletop {
    /// An empty table with the gripper parked above it.
    pub fn new(config: &SimConfig) -> Result<Self, SimError> {
        let grid = config.grid()?;
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, 0.0, -9.81);
        world.integration_parameters.dt = 1.0 / config.physics_hz;
        // Objects are 5 cm: the default unit of 1 m leaves contacts stale and lets fingers
        // sink into objects.
        world.integration_parameters.length_unit = 0.1;
        // Contacts between moving bodies are springs whose stiffness scales with the bodies'
        // mass (m (2 pi f)^2): at rapier's default 30 Hz a 75 g cube squeezed by 100 N pads
        // gives way by centimetres and the fingers pass through it; at 120 Hz by 4 mm a side.
        world.integration_parameters.contact_softness = SpringCoefficients::new(120.0, 10.0);
        // The gripper's linkage (three bodies a side, held by joints to the palm and to each
        // other) holds its arcs to a millimetre with two solver passes per substep; with one,
        // the fingers tilt by a degree and a half and bounce at the open stop.
        world.integration_parameters.num_internal_pgs_iterations = 2;

        world.insert(
            RigidBodyBuilder::fixed().translation(Vector::new(0.0, 0.0, -0.05)),
            material::bullet(
                ColliderBuilder::cuboid(FLOOR_HALF_SIDE, FLOOR_HALF_SIDE, 0.05),
                TABLE_FRICTION,
            )
            .collision_groups(InteractionGroups::new(
                TABLE_GROUP,
                OBJECT_GROUP | GRIPPER_GROUP,
                InteractionTestMode::And,
            )),
        );
        let gripper = Gripper::new(&mut world);
        Ok(Self {
            config: config.clone(),
            grid,
            world,
            objects: Vec::new(),
            gripper,
            physics_steps: 0,
            physics_time: Duration::ZERO,
        })
    }

    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// An exact copy to try an action on while this scene stays as it is: the bodies,
    /// colliders, joints, islands and contacts as they are now, with fresh pipelines (the
    /// per-step workspaces that rapier's own world snapshots leave out too), so the copy
    /// steps as this scene would.
    pub fn replica(&self) -> Self {
        let world = &self.world;
        Self {
            config: self.config.clone(),
            grid: self.grid,
            world: PhysicsWorld {
                gravity: world.gravity,
                integration_parameters: world.integration_parameters,
                physics_pipeline: PhysicsPipeline::new(),
                collision_pipeline: CollisionPipeline::new(),
                islands: world.islands.clone(),
                broad_phase: world.broad_phase.clone(),
                narrow_phase: world.narrow_phase.clone(),
                bodies: world.bodies.clone(),
                colliders: world.colliders.clone(),
                impulse_joints: world.impulse_joints.clone(),
                multibody_joints: world.multibody_joints.clone(),
                soft_bodies: world.soft_bodies.clone(),
                ccd_solver: CCDSolver::new(),
            },
            objects: self.objects.clone(),
            gripper: self.gripper.clone(),
            physics_steps: self.physics_steps,
            physics_time: self.physics_time,
        }
    }

    pub fn grid(&self) -> PixelGrid {
        self.grid
    }

    /// Adds a block at rest at the given pose; ids are unique and never 0 (the table).
    pub fn add_object(
        &mut self,
        id: ObjectId,
        kind: ShapeKind,
        colour: [u8; 3],
        pose: Pose,
    ) -> Result<(), SimError> {
        if id == 0 || self.objects.iter().any(|o| o.id == id) {
            return Err(SimError::ObjectId(id));
        }
        let shapes: Vec<(Pose, SharedShape)> = kind
            .parts()
            .iter()
            .map(|part| {
                let hull = SharedShape::convex_hull(&part.vertices)
                    .expect("catalogue parts are non-degenerate");
                (Pose::IDENTITY, hull)
            })
            .collect();
        let collider = material::bullet(ColliderBuilder::compound(shapes), OBJECT_FRICTION)
            .mass(OBJECT_MASS)
            .collision_groups(InteractionGroups::new(
                OBJECT_GROUP,
                TABLE_GROUP | OBJECT_GROUP | GRIPPER_GROUP,
                InteractionTestMode::And,
            ));
        let (body, _) = self
            .world
            .insert(RigidBodyBuilder::dynamic().pose(pose), collider);
        self.objects.push(Object {
            id,
            kind,
            colour,
            body,
        });
        Ok(())
    }

    /// The objects on the table, in insertion order.
    pub fn objects(&self) -> impl Iterator<Item = ObjectView> + '_ {
        self.objects.iter().map(|o| ObjectView {
            id: o.id,
            kind: o.kind,
            colour: o.colour,
            pose: *self.world.bodies[o.body].position(),
        })
    }

    pub fn object(&self, id: ObjectId) -> Option<ObjectView> {
        self.objects().find(|o| o.id == id)
    }

    pub fn object_count(&self) -> usize {
        self.objects.len()
    }

    /// Physics steps taken since construction.
    pub fn physics_steps(&self) -> u64 {
        self.physics_steps
    }

    /// Wall-clock time spent inside rapier's step since construction (what is left of an
    /// action's time is the primitives' own work).
    pub fn physics_time(&self) -> Duration {
        self.physics_time
    }

    /// One physics step.
    pub fn step(&mut self) {
        let start = Instant::now();
        self.world.step();
        self.physics_time += start.elapsed();
        self.physics_steps += 1;
    }

    /// Steps until every object has been at rest for a few steps in a row, at most
    /// `settle_max_s`, then removes the objects that left the scene.
    pub fn settle(&mut self) -> SettleReport {
        let max_steps = (self.config.settle_max_s * self.config.physics_hz).ceil() as u32;
        let mut quiet = 0;
        let mut steps = 0;
        while steps < max_steps && quiet < REST_STEPS {
            self.step();
            steps += 1;
            quiet = if self.all_at_rest() { quiet + 1 } else { 0 };
        }
        SettleReport {
            steps,
            at_rest: quiet >= REST_STEPS,
            removed: self.remove_out_of_view(),
        }
    }

    fn all_at_rest(&self) -> bool {
        self.objects.iter().all(|o| {
            let body = &self.world.bodies[o.body];
            body.is_sleeping()
                || (body.linvel().length() < REST_LINEAR && body.angvel().length() < REST_ANGULAR)
        })
    }

    /// Removes the objects that left the scene, and returns their ids: those the camera sees
    /// none of (not even hidden under another), and any that fell below the table.
    pub(crate) fn remove_out_of_view(&mut self) -> Vec<ObjectId> {
        let fallen: Vec<ObjectId> = self
            .objects()
            .filter(|o| {
                o.pose.translation.z < FALLEN_Z || !footprint::in_view(o.kind, &o.pose, self.grid)
            })
            .map(|o| o.id)
            .collect();
        for &id in &fallen {
            self.remove_object(id);
        }
        fallen
    }

    /// Whether `body` is one of the objects on the table.
    pub(crate) fn is_object(&self, body: RigidBodyHandle) -> bool {
        self.objects.iter().any(|o| o.body == body)
    }

    /// Takes an object out of the world (after a grasp, or when it fell off).
    pub fn remove_object(&mut self, id: ObjectId) -> bool {
        let Some(index) = self.objects.iter().position(|o| o.id == id) else {
            return false;
        };
        let object = self.objects.remove(index);
        self.world.remove_body(object.body);
        true
    }
}
