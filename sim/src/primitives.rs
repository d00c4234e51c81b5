//! The push and grasp primitives: a pixel and a rotation index in, a physically simulated
//! motion of the gripper, an outcome out. Nothing is teleported or attached: a grasp holds
//! what friction between the fingers holds.

use std::f32::consts::PI;

use rapier3d::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera::Heightmaps;
use crate::error::SimError;
use crate::gripper::{JAWS_CLOSED_GAP, Jaws, pad_end_height};
use crate::tabletop::{ObjectId, Tabletop};
use crate::workspace;

/// Number of gripper rotations; rotation k is the angle k * 22.5 degrees, counter-clockwise
/// from +x seen from above.
pub const ROTATIONS: u8 = 16;

/// Push: the local surface height is the highest point within this half-width of the start
/// (the original's 11 x 11 window at 2 mm, half a finger width)...
const PUSH_WINDOW_HALF: f32 = 0.01;
/// ...and the tool point goes 1 cm below it (`main.py`, `safe_z_position`), then 2.6 cm up
/// (`robot.py`, `push`): the closed pads' ends 6.6 mm below the surface. Over the bare table
/// that is 6.6 mm into it, where the original's floor stops them; here the tool stops where
/// the pads' ends meet the table: driven into it, rapier's joints let the fingers lag behind
/// the palm and pass through what they push.
const PUSH_TOOL_ABOVE_SURFACE: f32 = -0.01 + 0.026;
/// Grasp: the tool point (`UR5_tip`) goes 4 cm below the surface at the pixel, but no lower
/// than 2 cm above the table (`robot.py`, `grasp`)...
const GRASP_DEPTH: f32 = 0.04;
const GRASP_MIN_HEIGHT: f32 = 0.02;
/// ...arriving from 0.15 m above it (`grasp_location_margin`); a push arrives from 0.1 m
/// above its start (`pushing_point_margin`).
const GRASP_APPROACH_HEIGHT: f32 = 0.15;
const PUSH_APPROACH_HEIGHT: f32 = 0.10;
/// Tool speeds (m/s).
const DESCEND_SPEED: f32 = 0.5;
const PUSH_SPEED: f32 = 0.25;
const LIFT_SPEED: f32 = 0.5;
/// Jaw closing time limit (s), and the finger speed below which the jaws have stopped.
const CLOSE_MAX_S: f32 = 0.3;
const CLOSE_STOPPED_SPEED: f32 = 0.002;
/// Time held still after the lift before the grasp is judged (s).
const HOLD_S: f32 = 0.1;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Primitive {
    Push,
    Grasp,
}

/// An action as the policy picks it: a primitive at a heightmap pixel and a rotation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Action {
    pub primitive: Primitive,
    pub rotation: u8,
    pub row: usize,
    pub col: usize,
}

impl Action {
    /// The action's angle in radians.
    pub fn angle(&self) -> f32 {
        rotation_angle(self.rotation)
    }
}

/// The angle of rotation k in radians.
pub fn rotation_angle(rotation: u8) -> f32 {
    rotation as f32 * 2.0 * PI / ROTATIONS as f32
}

/// The rotation whose angle is nearest `angle` (radians, any turn).
pub fn nearest_rotation(angle: f32) -> u8 {
    let step = 2.0 * PI / ROTATIONS as f32;
    ((angle / step).round() as i32).rem_euclid(ROTATIONS as i32) as u8
}

/// What an action did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ActionOutcome {
    /// For a grasp: the object held after the lift (success), which has left the scene.
    pub grasped: Option<ObjectId>,
    /// Gap between the fingers after the lift (grasps; metres).
    pub final_opening: f32,
    /// Tool path: where the tool point (the scene's `UR5_tip`) started and ended the working
    /// motion.
    pub start: [f32; 3],
    pub end: [f32; 3],
    /// Objects that left the scene (the camera sees none of them) during the action or the
    /// settle after it.
    pub removed: Vec<ObjectId>,
    /// Physics steps the action took, settle included.
    pub physics_steps: u32,
    /// Whether the scene came to rest afterwards within the settle bound.
    pub settled: bool,
}

impl ActionOutcome {
    pub fn grasp_succeeded(&self) -> bool {
        self.grasped.is_some()
    }
}

/// How high above the table a push from pixel (`row`, `col`) lowers the closed pads' ends:
/// `PUSH_TOOL_ABOVE_SURFACE` over the highest point of the window around the start, but
/// not into the table.
pub fn push_pad_ends_height(observation: &Heightmaps, row: usize, col: usize) -> f32 {
    let side = observation.side();
    let half = (PUSH_WINDOW_HALF / observation.grid.pixel_size()).round() as usize;
    let mut surface: f32 = 0.0;
    for r in row.saturating_sub(half)..=(row + half).min(side - 1) {
        for c in col.saturating_sub(half)..=(col + half).min(side - 1) {
            surface = surface.max(observation.height[observation.index(r, c)]);
        }
    }
    (surface + PUSH_TOOL_ABOVE_SURFACE + pad_end_height(Jaws::Closed)).max(0.0)
}

/// Where a grasp at pixel (`row`, `col`) lowers the tool point: [`GRASP_DEPTH`] below the
/// surface there, but no lower than [`GRASP_MIN_HEIGHT`].
fn grasp_tool_height(observation: &Heightmaps, row: usize, col: usize) -> f32 {
    let surface = observation.height[observation.index(row, col)];
    (surface - GRASP_DEPTH).max(GRASP_MIN_HEIGHT)
}

/// How high above the table a grasp at pixel (`row`, `col`) lowers the open pads' ends: at
/// the bottom of its descent, before the jaws close and sweep them down.
pub fn grasp_pad_ends_height(observation: &Heightmaps, row: usize, col: usize) -> f32 {
    grasp_tool_height(observation, row, col) + pad_end_height(Jaws::Open)
}

impl Tabletop {
    /// Executes an action chosen on `observation`, which must be a rendering of this scene on
    /// this tabletop's grid (the heights at the pixel set the working height, as the
    /// original's).
    pub fn act(
        &mut self,
        action: &Action,
        observation: &Heightmaps,
    ) -> Result<ActionOutcome, SimError> {
        let grid = self.grid();
        if observation.grid != grid {
            return Err(SimError::GridMismatch {
                got: observation.side(),
                want: grid.side(),
            });
        }
        if action.rotation >= ROTATIONS {
            return Err(SimError::Rotation(action.rotation));
        }
        if action.row >= grid.side() || action.col >= grid.side() {
            return Err(SimError::Pixel {
                row: action.row,
                col: action.col,
                side: grid.side(),
            });
        }
        let steps_before = self.physics_steps();
        let mut outcome = match action.primitive {
            Primitive::Push => self.push(action, observation),
            Primitive::Grasp => self.grasp(action, observation),
        };
        self.gripper.park(&mut self.world);
        let settle = self.settle();
        outcome.removed.extend(settle.removed);
        outcome.settled = settle.at_rest;
        outcome.physics_steps = (self.physics_steps() - steps_before) as u32;
        Ok(outcome)
    }

    fn push(&mut self, action: &Action, observation: &Heightmaps) -> ActionOutcome {
        let [x, y] = self.grid().pixel_centre(action.row, action.col);
        let z = push_pad_ends_height(observation, action.row, action.col)
            - pad_end_height(Jaws::Closed);
        let angle = action.angle();
        let length = self.config().push_length;
        let rotation = Rotation::from_rotation_z(angle);
        let above = Vector::new(x, y, z + PUSH_APPROACH_HEIGHT);
        self.gripper.place(
            &mut self.world,
            Pose::from_parts(above, rotation),
            Jaws::Closed,
        );
        let start = self.lower_tool(Vector::new(x, y, z), rotation);
        let end = Vector::new(
            (x + length * angle.cos()).clamp(workspace::X_MIN, workspace::X_MAX),
            (y + length * angle.sin()).clamp(workspace::Y_MIN, workspace::Y_MAX),
            start.z,
        );
        self.move_tool(end, rotation, PUSH_SPEED);
        self.move_tool(end + Vector::Z * PUSH_APPROACH_HEIGHT, rotation, LIFT_SPEED);
        let removed = self.remove_out_of_view();
        ActionOutcome {
            start: start.to_array(),
            end: end.to_array(),
            removed,
            ..ActionOutcome::default()
        }
    }

    fn grasp(&mut self, action: &Action, observation: &Heightmaps) -> ActionOutcome {
        let grid = self.grid();
        let [x, y] = grid.pixel_centre(action.row, action.col);
        let z = grasp_tool_height(observation, action.row, action.col);
        let rotation = Rotation::from_rotation_z(action.angle());
        let above = Vector::new(x, y, z + GRASP_APPROACH_HEIGHT);
        self.gripper.place(
            &mut self.world,
            Pose::from_parts(above, rotation),
            Jaws::Open,
        );
        let start = Vector::new(x, y, z);
        self.move_tool(start, rotation, DESCEND_SPEED);

        self.gripper.command(&mut self.world, Jaws::Closed);
        let close_steps = self.seconds_to_steps(CLOSE_MAX_S);
        for i in 0..close_steps {
            self.gripper
                .drive_to(&mut self.world, Pose::from_parts(start, rotation));
            self.step();
            if i > 5 && self.gripper.finger_speed(&self.world) < CLOSE_STOPPED_SPEED {
                break;
            }
        }
        let lift = self.config().grasp_lift;
        let lifted = start + Vector::Z * lift;
        self.move_tool(lifted, rotation, LIFT_SPEED);
        for _ in 0..self.seconds_to_steps(HOLD_S) {
            self.gripper
                .drive_to(&mut self.world, Pose::from_parts(lifted, rotation));
            self.step();
        }

        // Judged as the original judges it: the jaws, still squeezing, did not close on
        // nothing, and what they hold is the highest object in the scene.
        let final_opening = self.gripper.opening(&self.world);
        let grasped = if final_opening > JAWS_CLOSED_GAP {
            self.highest_object()
        } else {
            None
        };
        if let Some(id) = grasped {
            self.remove_object(id);
        }
        self.gripper.command(&mut self.world, Jaws::Open);
        let removed = self.remove_out_of_view();
        ActionOutcome {
            grasped,
            final_opening,
            start: start.to_array(),
            end: lifted.to_array(),
            removed,
            ..ActionOutcome::default()
        }
    }

    /// The object whose origin is highest: after a lift, the one in the jaws.
    fn highest_object(&self) -> Option<ObjectId> {
        self.objects()
            .max_by(|a, b| a.pose.translation.z.total_cmp(&b.pose.translation.z))
            .map(|o| o.id)
    }

    /// Moves the tool in a straight line at a speed, position-controlled as the original's
    /// arm: what is in the way is pushed aside.
    fn move_tool(&mut self, target: Vector, rotation: Rotation, speed: f32) {
        self.move_tool_until(target, rotation, speed, |_| false);
    }

    /// Lowers the tool to `target`; under `guarded_push_descent` (why: its doc), stops where
    /// the gripper comes to bear on an object, as an arm's guarded move stops on contact.
    /// Returns where the tool stopped.
    fn lower_tool(&mut self, target: Vector, rotation: Rotation) -> Vector {
        let guarded = self.config().guarded_push_descent;
        self.move_tool_until(target, rotation, DESCEND_SPEED, |tabletop| {
            let is_object = |body| tabletop.is_object(body);
            guarded && tabletop.gripper.bears_on(&tabletop.world, is_object)
        })
    }

    /// Drives the tool in a straight line to `target` at `speed`, a physics step at a time,
    /// until `stop` holds after a step; returns where the tool is then.
    fn move_tool_until(
        &mut self,
        target: Vector,
        rotation: Rotation,
        speed: f32,
        stop: impl Fn(&Self) -> bool,
    ) -> Vector {
        let from = self.gripper.tool_pose(&self.world).translation;
        let distance = (target - from).length();
        let steps = ((distance / speed) * self.config().physics_hz)
            .ceil()
            .max(1.0) as u32;
        for i in 1..=steps {
            let at = from.lerp(target, i as f32 / steps as f32);
            self.gripper
                .drive_to(&mut self.world, Pose::from_parts(at, rotation));
            self.step();
            if stop(self) {
                return self.gripper.tool_pose(&self.world).translation;
            }
        }
        target
    }

    fn seconds_to_steps(&self, seconds: f32) -> u32 {
        (seconds * self.config().physics_hz).ceil() as u32
    }
}
