//! Scenes: random drops, as the original's training scenes, and arranged scenes from files.

use std::f32::consts::TAU;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rapier3d::prelude::*;

use crate::arrangement::Arrangement;
use crate::catalogue::{SLOT_COLOURS, ShapeKind};
use crate::config::SimConfig;
use crate::error::SimError;
use crate::tabletop::{ObjectId, SettleReport, Tabletop};
use crate::workspace;

/// Extra time after a drop's free fall before the next object is released (s).
const DROP_GAP_S: f32 = 0.1;

/// How a random scene came out: the objects dropped and the settle that followed (whose
/// `removed` lists objects that left the table).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneReport {
    pub seed: u64,
    pub dropped: Vec<(ObjectId, ShapeKind)>,
    pub settle: SettleReport,
}

impl Tabletop {
    /// Drops `objects` random blocks one at a time from `drop_height`, uniformly over the
    /// central `drop_square` with a uniformly random orientation, then settles. Object k
    /// (from 1) takes slot colour k - 1 (mod 10). The same seed gives the same scene.
    pub fn random(
        config: &SimConfig,
        objects: usize,
        seed: u64,
    ) -> Result<(Self, SceneReport), SimError> {
        if objects > 255 {
            return Err(SimError::TooManyObjects(objects));
        }
        let mut tabletop = Self::new(config)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let fall_s = (2.0 * config.drop_height / 9.81).sqrt() + DROP_GAP_S;
        let fall_steps = (fall_s * config.physics_hz).ceil() as u32;
        let half = config.drop_square / 2.0;
        let mut dropped = Vec::with_capacity(objects);
        for k in 0..objects {
            let id = (k + 1) as ObjectId;
            let kind = ShapeKind::ALL[rng.random_range(0..ShapeKind::ALL.len())];
            let x = workspace::CENTRE[0] + rng.random_range(-half..half);
            let y = workspace::CENTRE[1] + rng.random_range(-half..half);
            let orientation = uniform_rotation(&mut rng);
            let pose = Pose::from_parts(Vector::new(x, y, config.drop_height), orientation);
            tabletop.add_object(id, kind, SLOT_COLOURS[k % SLOT_COLOURS.len()], pose)?;
            for _ in 0..fall_steps {
                tabletop.step();
            }
            dropped.push((id, kind));
        }
        let settle = tabletop.settle();
        Ok((
            tabletop,
            SceneReport {
                seed,
                dropped,
                settle,
            },
        ))
    }

    /// Places an arrangement's objects exactly where the file says, without settling (call
    /// `settle` to let physics take over).
    pub fn from_arrangement(
        config: &SimConfig,
        arrangement: &Arrangement,
    ) -> Result<Self, SimError> {
        let mut tabletop = Self::new(config)?;
        for object in &arrangement.objects {
            tabletop.add_object(object.id, object.shape, object.colour, object.pose())?;
        }
        Ok(tabletop)
    }
}

/// A rotation drawn uniformly over SO(3) (Shoemake's method).
fn uniform_rotation(rng: &mut ChaCha8Rng) -> Rotation {
    let (u1, u2, u3): (f32, f32, f32) = (rng.random(), rng.random(), rng.random());
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    Rotation::from_xyzw(
        a * (TAU * u2).sin(),
        a * (TAU * u2).cos(),
        b * (TAU * u3).sin(),
        b * (TAU * u3).cos(),
    )
    .normalize()
}
