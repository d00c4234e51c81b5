//! A parallel-jaw gripper: a kinematic palm carrying two dynamic fingers on prismatic joints
//! driven by force-limited velocity motors, so what it holds is decided by contact and
//! friction alone.
//!
//! The palm's frame is the tool frame: its origin is the centre of the fingertips' lower end,
//! z points up and x is the jaw axis (the fingers close along it).

use rapier3d::prelude::*;

use crate::collision::{GRIPPER_GROUP, OBJECT_GROUP, TABLE_GROUP};
use crate::workspace;

/// Finger half extents: along the jaw, across it, and vertically (a 5 cm finger).
const FINGER_HALF: [f32; 3] = [0.005, 0.01, 0.025];
/// Gap between the fingers' inner faces when fully open.
const MAX_OPENING: f32 = 0.10;
/// A finger of about 100 g, weightless on its joint: too light a finger with a strong motor
/// passes through what it grips.
const FINGER_MASS: f32 = 0.1;
/// Rubber pads.
const FINGER_FRICTION: f32 = 1.0;
/// The jaw motors, as the original drives its RG2's one joint (`robot.py`, `close_gripper`
/// and `open_gripper`): closing at 0.5 m/s with a force of 100 N, opening at 0.5 m/s with
/// 20 N. The joint's speed is taken as the gap's (each finger moves at half of it) and its
/// force as each pad's squeeze.
const JAW_SPEED: f32 = 0.5;
const GRIP_FORCE: f32 = 100.0;
const OPEN_FORCE: f32 = 20.0;
/// Damping of the velocity motors (N s/m): high enough that a motor holds its speed up to
/// its force limit, as a velocity-controlled joint does, rather than acting as a spring.
const MOTOR_DAMPING: f32 = 1.0e4;
/// Where the gripper waits between actions, well clear of the scene.
const PARK_HEIGHT: f32 = 1.0;

/// Where the jaw motors drive the fingers: to the joints' open or closed limit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Jaws {
    Open,
    Closed,
}

impl Jaws {
    /// The gap between the pads at this limit.
    fn gap(self) -> f32 {
        match self {
            Jaws::Open => MAX_OPENING,
            Jaws::Closed => 0.0,
        }
    }
}

#[derive(Clone)]
pub(crate) struct Gripper {
    palm: RigidBodyHandle,
    fingers: [RigidBodyHandle; 2],
    joints: [ImpulseJointHandle; 2],
}

/// The joint coordinate of a finger (distance of its centre from the tool axis) for a gap.
fn finger_offset(opening: f32) -> f32 {
    opening / 2.0 + FINGER_HALF[0]
}

impl Gripper {
    pub(crate) fn new(world: &mut PhysicsWorld) -> Self {
        let groups = InteractionGroups::new(
            GRIPPER_GROUP,
            TABLE_GROUP | OBJECT_GROUP,
            InteractionTestMode::And,
        );
        let finger_length = 2.0 * FINGER_HALF[2];
        let (palm, _) = world.insert(
            RigidBodyBuilder::kinematic_position_based().translation(park_point()),
            ColliderBuilder::cuboid(MAX_OPENING / 2.0 + 0.015, 0.02, 0.01)
                .translation(Vector::new(0.0, 0.0, finger_length + 0.01))
                .collision_groups(groups),
        );
        let mut fingers = [palm; 2];
        let mut joints = [ImpulseJointHandle::invalid(); 2];
        for (i, side) in [1.0f32, -1.0].into_iter().enumerate() {
            let axis = Vector::new(side, 0.0, 0.0);
            let offset = finger_offset(MAX_OPENING);
            let (finger, _) = world.insert(
                RigidBodyBuilder::dynamic()
                    .translation(park_point() + Vector::new(side * offset, 0.0, FINGER_HALF[2]))
                    .gravity_scale(0.0)
                    .can_sleep(false),
                ColliderBuilder::cuboid(FINGER_HALF[0], FINGER_HALF[1], FINGER_HALF[2])
                    .mass(FINGER_MASS)
                    .friction(FINGER_FRICTION)
                    .collision_groups(groups),
            );
            let joint = PrismaticJointBuilder::new(axis)
                .local_anchor1(Vector::new(0.0, 0.0, FINGER_HALF[2]))
                .local_anchor2(Vector::ZERO)
                .limits([FINGER_HALF[0], finger_offset(MAX_OPENING)])
                .motor_model(MotorModel::ForceBased)
                .motor_velocity(JAW_SPEED / 2.0, MOTOR_DAMPING)
                .motor_max_force(OPEN_FORCE)
                .contacts_enabled(false);
            fingers[i] = finger;
            joints[i] = world.insert_impulse_joint(palm, finger, joint);
        }
        Self {
            palm,
            fingers,
            joints,
        }
    }

    /// Puts the gripper at a tool pose with its jaws at a limit, at rest, before an action
    /// starts: the gripper arrives from out of the scene, so nothing it touches is disturbed.
    pub(crate) fn place(&self, world: &mut PhysicsWorld, tool: Pose, jaws: Jaws) {
        world.bodies[self.palm].set_position(tool, true);
        let offset = finger_offset(jaws.gap());
        for (i, side) in [1.0f32, -1.0].into_iter().enumerate() {
            let local = Vector::new(side * offset, 0.0, FINGER_HALF[2]);
            let finger = &mut world.bodies[self.fingers[i]];
            finger.set_position(
                Pose::from_parts(tool.transform_point(local), tool.rotation),
                true,
            );
            finger.set_linvel(Vector::ZERO, true);
            finger.set_angvel(Vector::ZERO, true);
        }
        self.command(world, jaws);
    }

    /// Moves the gripper back to its parking place, open.
    pub(crate) fn park(&self, world: &mut PhysicsWorld) {
        self.place(world, Pose::from_translation(park_point()), Jaws::Open);
    }

    /// Drives the jaws towards a limit; closed on an object, they squeeze it with the full
    /// grip force.
    pub(crate) fn command(&self, world: &mut PhysicsWorld, jaws: Jaws) {
        let (speed, force) = match jaws {
            Jaws::Open => (JAW_SPEED / 2.0, OPEN_FORCE),
            Jaws::Closed => (-JAW_SPEED / 2.0, GRIP_FORCE),
        };
        for joint in self.joints {
            if let Some(joint) = world.impulse_joints.get_mut(joint, true) {
                joint
                    .data
                    .set_motor_velocity(JointAxis::LinX, speed, MOTOR_DAMPING)
                    .set_motor_max_force(JointAxis::LinX, force);
            }
        }
    }

    /// Drives the palm towards a tool pose over the next step.
    pub(crate) fn drive_to(&self, world: &mut PhysicsWorld, tool: Pose) {
        world.bodies[self.palm].set_next_kinematic_position(tool);
    }

    pub(crate) fn tool_pose(&self, world: &PhysicsWorld) -> Pose {
        *world.bodies[self.palm].position()
    }

    /// The gap between the fingers' inner faces now.
    pub(crate) fn opening(&self, world: &PhysicsWorld) -> f32 {
        let palm = world.bodies[self.palm].position();
        let [a, b] = self.fingers.map(|f| {
            palm.inverse_transform_point(world.bodies[f].translation())
                .x
        });
        (a - b) - 2.0 * FINGER_HALF[0]
    }

    /// The fastest finger speed relative to the palm (m/s), to tell when the jaws stopped.
    pub(crate) fn finger_speed(&self, world: &PhysicsWorld) -> f32 {
        let palm = world.bodies[self.palm].linvel();
        self.fingers
            .iter()
            .map(|&f| (world.bodies[f].linvel() - palm).length())
            .fold(0.0, f32::max)
    }
}

fn park_point() -> Vector {
    Vector::new(workspace::CENTRE[0], workspace::CENTRE[1], PARK_HEIGHT)
}
