//! The authors' gripper, an OnRobot RG2 as their V-REP scene defines it
//! (`simulation.ttt`, decoded by `shared/reference/vrep-scene/read_ttt.py`): a kinematic
//! palm (the arm's IK target moves it) carrying two fingers, each held parallel to the palm
//! by a parallelogram of two links, so a finger moves on a 55 mm arc and sweeps down as the
//! jaws close. One force-limited velocity motor sets the gap between the pads, as the
//! scene's `RG2_openCloseJoint` does; what the jaws hold is decided by contact and friction.
//!
//! The palm's frame is the tool frame: its origin is the scene's `UR5_tip` (within 2 mm of
//! the pads' centre in the stored pose), z points up, away from the fingertips, and x is the
//! jaw axis. A height here is 0.1855 m (`UR5_tip` in the RG2 frame) minus the RG2 frame's z;
//! every size below is the scene's, its object named beside it. The finger on +x is the
//! scene's left finger; the other is its mirror image (the stored pose is symmetric to
//! 0.7 mm).
//!
//! The gripper's parts and its motions share every measure above, so they stay in one file; its
//! tests take it past 450 lines.

use std::f32::consts::PI;

use rapier3d::prelude::*;

use crate::collision::{GRIPPER_GROUP, OBJECT_GROUP, TABLE_GROUP};
use crate::material;
use crate::workspace;

/// Length of both links of a finger's parallelogram, pivot to finger (`RG2_leftJoint0` to
/// `RG2_leftJoint1`, and `Joint2` to `Joint4`: 55.0 mm on both sides).
const LINK_LENGTH: f32 = 0.05503;
/// Where the two links of the +x finger turn on the palm (`RG2_leftJoint0` at RG2 (17.0,
/// 100.5) mm, `RG2_leftJoint2` at (7.5, 117.0) mm).
const LINK0_PIVOT: [f32; 2] = [0.017, 0.085];
const LINK2_PIVOT: [f32; 2] = [0.0075, 0.0685];
/// The links' angle from straight down in the stored pose (27.65 degrees, the mean of both
/// sides), where the gap between the pads is `STORED_GAP`.
const STORED_ANGLE: f32 = 27.65 * PI / 180.0;
const STORED_GAP: f32 = 0.04689;
/// The gap's limits: fully open at the open/close joint's upper limit (+0.0538 m: gap =
/// 0.04693 m + the joint's position), closed where `RG2_leftJoint0`'s limit stops the
/// links (2.97 degrees: a 1.5 mm gap).
const OPEN_GAP: f32 = 0.04693 + 0.0538;
const CLOSED_GAP: f32 = 0.0015;
/// The original judges a grasp by whether the re-closed jaws pass -0.045 on the open/close
/// joint (`robot.py`, `close_gripper`): a gap below 0.04693 - 0.045 m is closed on nothing.
pub(crate) const JAWS_CLOSED_GAP: f32 = 0.04693 - 0.045;

/// One of the jaws' lower parts seen from above, in the tool frame, at a limit of the jaws:
/// its extent along the closing axis (x, the direction a push moves in) and across it (y),
/// and how far its lower face is above the pads' ends. Where a push's or a grasp's descent
/// lands, what lies under a part higher than its lower face is pressed into the table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JawsPart {
    pub along: [f32; 2],
    pub across: [f32; 2],
    pub above_pad_ends: f32,
}

/// Both fingers' parts (pads, their backing and the knuckles) with the jaws at `jaws`: closed
/// as a push carries them (41 mm along the closing axis at the knuckles, 20 mm across), open
/// as a grasp comes down.
pub fn jaws_parts(jaws: Jaws) -> Vec<JawsPart> {
    let shift = link_end(LINK0_PIVOT, link_angle(jaws.gap())) - stored_origin();
    let pad_ends = pad_end_height(jaws);
    [1.0f32, -1.0]
        .into_iter()
        .flat_map(|side| {
            FINGER_PARTS.iter().chain(&PAD_PARTS).map(move |part| {
                let x = [part.min[0], part.max[0]].map(|x| side * (x + shift.x));
                JawsPart {
                    along: [x[0].min(x[1]), x[0].max(x[1])],
                    across: [part.min[1], part.max[1]],
                    above_pad_ends: part.min[2] + shift.z - pad_ends,
                }
            })
        })
        .collect()
}

/// A part of the gripper as a box in the tool frame in the stored pose (+x finger): its
/// lowest and highest corner.
struct Part {
    min: [f32; 3],
    max: [f32; 3],
}

/// The finger (`RG2_leftLink1`, friction 0.71): the pad's backing (`Shape9`) and the
/// knuckle the links hold (`Shape5`), each as its mesh's bounding box.
const FINGER_PARTS: [Part; 2] = [
    Part {
        min: [0.02695, -0.010, -0.0166],
        max: [0.03505, 0.010, 0.0129],
    },
    Part {
        min: [0.02815, -0.0058, 0.0115],
        max: [0.04315, 0.0058, 0.0332],
    },
];
/// The pad (`RG2_leftTouch`, friction 0.5), three pure cuboids: 4.5 x 20 x 23.8 mm
/// (`Cuboid2`) and two tip pieces (`Cuboid3`, `Cuboid4`). Its inner face is at half the
/// stored gap.
const PAD_PARTS: [Part; 3] = [
    Part {
        min: [STORED_GAP / 2.0, -0.010, -0.0110],
        max: [STORED_GAP / 2.0 + 0.0045, 0.010, 0.0129],
    },
    Part {
        min: [STORED_GAP / 2.0, -0.009, -0.0144],
        max: [STORED_GAP / 2.0 + 0.0035, 0.009, -0.0109],
    },
    Part {
        min: [STORED_GAP / 2.0, -0.00625, -0.0166],
        max: [STORED_GAP / 2.0 + 0.0035, 0.00625, -0.0144],
    },
];
/// The palm's collision shapes: the base plate (`RG2`, a 48.2 x 52 x 9 mm cuboid, friction
/// 1.0) and the housing (`RG2_upperBase`, friction 0.71), as the bounding boxes of its
/// lower mesh and of its upper meshes with the side plates.
const BASE_PLATE: Part = Part {
    min: [-0.0241, -0.026, 0.1810],
    max: [0.0241, 0.026, 0.1900],
};
const HOUSING: [Part; 2] = [
    Part {
        min: [-0.0329, -0.018, 0.0627],
        max: [0.0319, 0.018, 0.1061],
    },
    Part {
        min: [-0.0303, -0.018, 0.0751],
        max: [0.0307, 0.018, 0.1884],
    },
];
/// The links' bars, measured along the link from its pivot and across it, from their
/// meshes' vertices (`RG2_leftLink0`: 13.4 to 59.9 mm along, 11.4 mm thick; `RG2_leftLink2`:
/// 6.6 to 59.9 mm along, 10 mm thick; both 20 mm wide).
const LINK0_BAR: [f32; 3] = [0.0134, 0.0599, 0.0114];
const LINK2_BAR: [f32; 3] = [0.0066, 0.0599, 0.0100];

/// Masses (`Mas`): every link and pad 0.04545 kg; the finger carries its link and its pad,
/// the second link its auxiliary mass (`RG2_leftAuxMass`). The palm is kinematic.
const PART_MASS: f32 = 0.04545;
/// Bullet 2.83 friction of the scene's materials: pads, links and housing, base plate.
const PAD_FRICTION: f32 = 0.5;
const LINK_FRICTION: f32 = 0.71;
const BASE_FRICTION: f32 = 1.0;

/// The jaw motor, as the original drives `RG2_openCloseJoint` (`robot.py`, `close_gripper`
/// and `open_gripper`): closing at 0.5 m/s with a force of 100 N, opening at 0.5 m/s with
/// 20 N. The joint sets the gap, so its speed is the gap's and its force the squeeze.
const JAW_SPEED: f32 = 0.5;
const GRIP_FORCE: f32 = 100.0;
const OPEN_FORCE: f32 = 20.0;
/// Damping of the velocity motor (N s/m): high enough that it holds its speed up to its
/// force limit, as a velocity-controlled joint does, rather than acting as a spring.
const MOTOR_DAMPING: f32 = 1.0e4;
/// Where the gripper waits between actions, well clear of the scene.
const PARK_HEIGHT: f32 = 1.0;

/// Where the jaw motor drives the fingers: to the joint's open or closed limit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Jaws {
    Open,
    Closed,
}

impl Jaws {
    /// The gap between the pads at this limit.
    fn gap(self) -> f32 {
        match self {
            Jaws::Open => OPEN_GAP,
            Jaws::Closed => CLOSED_GAP,
        }
    }
}

/// The links' angle from straight down at a gap: the pads move out by the link's sine.
fn link_angle(gap: f32) -> f32 {
    (STORED_ANGLE.sin() + (gap - STORED_GAP) / (2.0 * LINK_LENGTH)).asin()
}

/// Where a finger's link ends (the +x finger's frame origin) in the tool frame, at a link
/// angle: its pivot plus the link, pointing down and out.
fn link_end(pivot: [f32; 2], angle: f32) -> Vector {
    Vector::new(
        pivot[0] + LINK_LENGTH * angle.sin(),
        0.0,
        pivot[1] - LINK_LENGTH * angle.cos(),
    )
}

/// The +x finger's frame origin in the stored pose, where its parts' boxes are given.
fn stored_origin() -> Vector {
    link_end(LINK0_PIVOT, STORED_ANGLE)
}

/// The height of the pads' lower ends in a finger's frame.
fn pad_end_on_finger() -> f32 {
    PAD_PARTS[2].min[2] - stored_origin().z
}

/// The height of the pads' lower ends above the tool point with the jaws at a limit: 15.5 mm
/// above it fully open, 22.6 mm below it closed.
pub(crate) fn pad_end_height(jaws: Jaws) -> f32 {
    link_end(LINK0_PIVOT, link_angle(jaws.gap())).z + pad_end_on_finger()
}

/// One side of the gripper: the finger and its two links. `side` is +1 for the finger on
/// +x, -1 for its mirror image.
#[derive(Clone)]
struct Side {
    side: f32,
    finger: RigidBodyHandle,
    links: [RigidBodyHandle; 2],
}

impl Side {
    /// A point of the +x finger's layout mirrored to this side.
    fn mirror(&self, v: Vector) -> Vector {
        Vector::new(self.side * v.x, v.y, v.z)
    }

    /// Each body's pose relative to the palm at a gap: the finger, then the links.
    fn local_poses(&self, gap: f32) -> [Pose; 3] {
        let angle = link_angle(gap);
        let finger = Pose::from_translation(self.mirror(link_end(LINK0_PIVOT, angle)));
        let link = |pivot: [f32; 2]| {
            Pose::from_parts(
                self.mirror(Vector::new(pivot[0], 0.0, pivot[1])),
                Rotation::from_rotation_y(-self.side * angle),
            )
        };
        [finger, link(LINK0_PIVOT), link(LINK2_PIVOT)]
    }
}

#[derive(Clone)]
pub(crate) struct Gripper {
    palm: RigidBodyHandle,
    sides: [Side; 2],
    jaw: ImpulseJointHandle,
}

/// A box part of the +x finger's layout as a collider on a body whose origin is `origin`
/// in the tool frame, mirrored to `side`.
fn part_collider(part: &Part, origin: Vector, side: f32) -> ColliderBuilder {
    let min = Vector::from(part.min);
    let max = Vector::from(part.max);
    let half = (max - min) / 2.0;
    let centre = (min + max) / 2.0 - origin;
    ColliderBuilder::cuboid(half.x, half.y, half.z).translation(Vector::new(
        side * centre.x,
        centre.y,
        centre.z,
    ))
}

/// A link's bar as a collider on the link's body (origin at its pivot, -z along the link).
fn bar_collider(bar: [f32; 3]) -> ColliderBuilder {
    let [from, to, thickness] = bar;
    ColliderBuilder::cuboid(thickness / 2.0, 0.01, (to - from) / 2.0).translation(Vector::new(
        0.0,
        0.0,
        -(from + to) / 2.0,
    ))
}

/// A gripper part's contact material: it touches the table and the objects, not itself.
fn gripper_material(collider: ColliderBuilder, friction: f32) -> ColliderBuilder {
    let groups = InteractionGroups::new(
        GRIPPER_GROUP,
        TABLE_GROUP | OBJECT_GROUP,
        InteractionTestMode::And,
    );
    material::bullet(collider, friction).collision_groups(groups)
}

impl Side {
    /// The finger (its link and its pad, each 0.045 kg, carried by its largest box) and its
    /// two links on side `side` (+1 or -1), placed as stored; not joined yet.
    fn insert(world: &mut PhysicsWorld, side: f32, stored_origin: Vector) -> Self {
        let finger = world.insert_body(RigidBodyBuilder::dynamic().can_sleep(false));
        for (parts, friction) in [
            (&FINGER_PARTS[..], LINK_FRICTION),
            (&PAD_PARTS, PAD_FRICTION),
        ] {
            for (i, part) in parts.iter().enumerate() {
                let collider = part_collider(part, stored_origin, side);
                let collider = if i == 0 {
                    collider.mass(PART_MASS)
                } else {
                    collider.density(0.0)
                };
                world.insert_collider(gripper_material(collider, friction), Some(finger));
            }
        }
        let links = [(LINK0_BAR, PART_MASS), (LINK2_BAR, 2.0 * PART_MASS)].map(|(bar, mass)| {
            let link = world.insert_body(RigidBodyBuilder::dynamic().can_sleep(false));
            world.insert_collider(
                gripper_material(bar_collider(bar).mass(mass), LINK_FRICTION),
                Some(link),
            );
            link
        });
        Self {
            side,
            finger,
            links,
        }
    }

    /// Joins the finger and its links to the palm. The finger stays parallel to the palm and
    /// moves in its plane; each link turns on the palm at its pivot and holds the finger at
    /// its end, so the finger moves on the links' arc. Every constraint removes a freedom no
    /// other one does (a redundant set leaves the iterative solver fighting itself and the
    /// fingers tilting): the second link, equal and parallel to the first, follows the
    /// finger, holding it in the scene's parallelogram.
    fn join_to(&self, world: &mut PhysicsWorld, palm: RigidBodyHandle, stored_origin: Vector) {
        let in_plane = JointAxesMask::LIN_X | JointAxesMask::LIN_Z;
        world.insert_impulse_joint(
            palm,
            self.finger,
            GenericJointBuilder::new(JointAxesMask::ANG_AXES | JointAxesMask::LIN_Y)
                .local_anchor2(-self.mirror(stored_origin))
                .contacts_enabled(false),
        );
        for (&link, pivot) in self.links.iter().zip([LINK0_PIVOT, LINK2_PIVOT]) {
            let on_palm = self.mirror(Vector::new(pivot[0], 0.0, pivot[1]));
            let on_finger = self.mirror(Vector::new(
                pivot[0] - LINK0_PIVOT[0],
                0.0,
                pivot[1] - LINK0_PIVOT[1],
            ));
            world.insert_impulse_joint(
                palm,
                link,
                RevoluteJointBuilder::new(Vector::Y)
                    .local_anchor1(on_palm)
                    .local_anchor2(Vector::ZERO)
                    .contacts_enabled(false),
            );
            world.insert_impulse_joint(
                link,
                self.finger,
                GenericJointBuilder::new(in_plane)
                    .local_anchor1(Vector::new(0.0, 0.0, -LINK_LENGTH))
                    .local_anchor2(on_finger)
                    .contacts_enabled(false),
            );
        }
    }
}

impl Gripper {
    pub(crate) fn new(world: &mut PhysicsWorld) -> Self {
        let palm = world.insert_body(RigidBodyBuilder::kinematic_position_based());
        world.insert_collider(
            gripper_material(part_collider(&BASE_PLATE, Vector::ZERO, 1.0), BASE_FRICTION),
            Some(palm),
        );
        for part in &HOUSING {
            world.insert_collider(
                gripper_material(part_collider(part, Vector::ZERO, 1.0), LINK_FRICTION),
                Some(palm),
            );
        }
        let stored_origin = stored_origin();
        let sides = [1.0f32, -1.0].map(|side| Side::insert(world, side, stored_origin));
        for s in &sides {
            s.join_to(world, palm, stored_origin);
        }
        // The open/close joint between the pads' inner faces: its coordinate is the gap, and
        // it keeps the fingers level with each other, as the scene's centre chain does.
        let face = |s: &Side| s.mirror(Vector::new(STORED_GAP / 2.0, 0.0, 0.0) - stored_origin);
        let jaw = world.insert_impulse_joint(
            sides[1].finger,
            sides[0].finger,
            GenericJointBuilder::new(JointAxesMask::LIN_Z)
                .local_anchor1(face(&sides[1]))
                .local_anchor2(face(&sides[0]))
                .limits(JointAxis::LinX, [CLOSED_GAP, OPEN_GAP])
                .motor_model(JointAxis::LinX, MotorModel::ForceBased)
                .motor_velocity(JointAxis::LinX, JAW_SPEED, MOTOR_DAMPING)
                .motor_max_force(JointAxis::LinX, OPEN_FORCE)
                .contacts_enabled(false),
        );
        let gripper = Self { palm, sides, jaw };
        gripper.park(world);
        gripper
    }

    /// Puts the gripper at a tool pose with its jaws at a limit, at rest, before an action
    /// starts: the gripper arrives from out of the scene, so nothing it touches is disturbed.
    pub(crate) fn place(&self, world: &mut PhysicsWorld, tool: Pose, jaws: Jaws) {
        world.bodies[self.palm].set_position(tool, true);
        for side in &self.sides {
            let bodies = [side.finger, side.links[0], side.links[1]];
            for (body, local) in bodies.into_iter().zip(side.local_poses(jaws.gap())) {
                let body = &mut world.bodies[body];
                body.set_position(tool * local, true);
                body.set_linvel(Vector::ZERO, true);
                body.set_angvel(Vector::ZERO, true);
            }
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
            Jaws::Open => (JAW_SPEED, OPEN_FORCE),
            Jaws::Closed => (-JAW_SPEED, GRIP_FORCE),
        };
        if let Some(joint) = world.impulse_joints.get_mut(self.jaw, true) {
            joint
                .data
                .set_motor_velocity(JointAxis::LinX, speed, MOTOR_DAMPING)
                .set_motor_max_force(JointAxis::LinX, force);
        }
    }

    /// Drives the palm towards a tool pose over the next step.
    pub(crate) fn drive_to(&self, world: &mut PhysicsWorld, tool: Pose) {
        world.bodies[self.palm].set_next_kinematic_position(tool);
    }

    pub(crate) fn tool_pose(&self, world: &PhysicsWorld) -> Pose {
        *world.bodies[self.palm].position()
    }

    /// The gap between the pads' inner faces now.
    pub(crate) fn opening(&self, world: &PhysicsWorld) -> f32 {
        let palm = world.bodies[self.palm].position();
        let [a, b] = self.sides.each_ref().map(|s| {
            palm.inverse_transform_point(world.bodies[s.finger].translation())
                .x
        });
        let stored_face = stored_origin().x - STORED_GAP / 2.0;
        (a - b) - 2.0 * stored_face
    }

    /// Whether a part of the gripper bears on a body `is_object` names, from above or below:
    /// an active contact whose normal is within 45 degrees of vertical (a finger brushing an
    /// object's side does not count).
    pub(crate) fn bears_on(
        &self,
        world: &PhysicsWorld,
        is_object: impl Fn(RigidBodyHandle) -> bool,
    ) -> bool {
        let parts = self
            .sides
            .iter()
            .flat_map(|s| [s.finger, s.links[0], s.links[1]])
            .chain([self.palm]);
        parts
            .flat_map(|body| world.bodies[body].colliders().iter().copied())
            .any(|collider| {
                world.contact_pairs_with(collider).any(|pair| {
                    let other = if pair.collider1 == collider {
                        pair.collider2
                    } else {
                        pair.collider1
                    };
                    world.colliders[other].parent().is_some_and(&is_object)
                        && pair.has_any_active_contact()
                        && pair
                            .manifolds()
                            .iter()
                            .any(|m| m.data.normal.z.abs() > std::f32::consts::FRAC_1_SQRT_2)
                })
            })
    }

    /// The fastest finger speed relative to the palm (m/s), to tell when the jaws stopped.
    pub(crate) fn finger_speed(&self, world: &PhysicsWorld) -> f32 {
        let palm = world.bodies[self.palm].linvel();
        self.sides
            .iter()
            .map(|s| (world.bodies[s.finger].linvel() - palm).length())
            .fold(0.0, f32::max)
    }
}

fn park_point() -> Vector {
    Vector::new(workspace::CENTRE[0], workspace::CENTRE[1], PARK_HEIGHT)
}

#[cfg(test)]
mod tests;
