//! The tabletop world pushgrasp learns in: a headless rapier scene of toy blocks on a table,
//! a top-down heightmap camera computed exactly from the geometry, physically simulated push
//! and grasp primitives, and the scene measurements the rewards need.
//!
//! Coordinates follow the original work: metres, z up, the table surface at z = 0 and the
//! workspace x in [-0.724, -0.276], y in [-0.224, 0.224]. Heightmap rows index y and columns
//! index x. This crate knows nothing of learning or transport.

pub mod arrangement;
pub mod camera;
pub mod catalogue;
mod collision;
pub mod config;
pub mod error;
mod footprint;
mod gripper;
pub mod mask_shape;
mod material;
pub mod measure;
pub mod primitives;
pub mod scene;
pub mod tabletop;
pub mod workspace;

pub use arrangement::{Arrangement, OriginalOptions, PlacedObject};
pub use camera::{Camera, Heightmaps};
pub use catalogue::{SLOT_COLOURS, ShapeKind};
pub use config::SimConfig;
pub use error::{ArrangementError, ConfigError, SimError, above};
pub use gripper::{Jaws, JawsPart, jaws_parts};
pub use mask_shape::MaskShape;
pub use primitives::{
    Action, ActionOutcome, Primitive, ROTATIONS, grasp_pad_ends_height, nearest_rotation,
    push_pad_ends_height, rotation_angle,
};
pub use rapier3d;
pub use scene::{Rows, SceneReport};
pub use tabletop::{ANY_OBJECT, ObjectId, ObjectView, SettleReport, Tabletop};
pub use workspace::PixelGrid;
