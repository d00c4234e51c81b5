//! Scenes: random drops, as the original's training scenes, and arranged scenes from files.

use std::f32::consts::TAU;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rapier3d::prelude::*;

use crate::arrangement::{Arrangement, PlacedObject};
use crate::catalogue::{SLOT_COLOURS, ShapeKind, box_around};
use crate::config::SimConfig;
use crate::error::SimError;
use crate::tabletop::{ObjectId, SettleReport, Tabletop};
use crate::workspace;

/// Extra time after a drop's free fall before the next object is released (s).
const DROP_GAP_S: f32 = 0.1;

/// Blocks laid touching before a random drop: `blocks` of them in `lines` lines side by
/// side (one line: a row; more: a packed cluster), the first lines the longer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rows {
    pub blocks: usize,
    pub lines: usize,
}

impl Rows {
    /// A plain drop.
    pub const NONE: Self = Self::line(0);

    /// `blocks` in one line.
    pub const fn line(blocks: usize) -> Self {
        Self { blocks, lines: 1 }
    }
}

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
        Self::random_with_rows(config, objects, Rows::NONE, seed)
    }

    /// As [`Tabletop::random`], but the first `rows.blocks` of the `objects` are first laid
    /// side by side in `rows.lines` lines, touching, lying on a face, at a random place and
    /// heading (the pattern of the paper's challenging arrangements, where neighbours spoil
    /// many of the goal's grasps); the others are then dropped as usual. Fewer than 2 blocks
    /// is a plain drop.
    pub fn random_with_rows(
        config: &SimConfig,
        objects: usize,
        rows: Rows,
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
        let row = if rows.blocks >= 2 {
            rows.blocks.min(objects)
        } else {
            0
        };
        if row > 0 {
            let kinds: Vec<ShapeKind> = (0..row)
                .map(|_| ShapeKind::ALL[rng.random_range(0..ShapeKind::ALL.len())])
                .collect();
            let laid = lay_rows(&kinds, rows.lines, half, &mut rng);
            for (k, (kind, pose)) in laid.into_iter().enumerate() {
                let id = (k + 1) as ObjectId;
                tabletop.add_object(id, kind, SLOT_COLOURS[k % SLOT_COLOURS.len()], pose)?;
                dropped.push((id, kind));
            }
        }
        for k in row..objects {
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

    /// The scene as it stands, as an arrangement that [`Tabletop::from_arrangement`]
    /// rebuilds (a random scene turned into a test case).
    pub fn to_arrangement(&self, name: Option<String>, goal: Option<ObjectId>) -> Arrangement {
        Arrangement {
            name,
            goal,
            objects: self
                .objects()
                .map(|o| PlacedObject::at(o.id, o.kind, o.colour, o.pose))
                .collect(),
        }
    }
}

/// Gap left between neighbours in a row (metres): touching, without starting interpenetrated.
const ROW_GAP: f32 = 0.0005;

/// Poses that lay `kinds` side by side in `lines` touching lines through a random point
/// within `half` of the workspace centre, at a random heading: each block lies on one of its
/// box faces that it rests flat on ([`rests_flat`]), turned a random quarter about the
/// vertical, just above the table.
fn lay_rows(
    kinds: &[ShapeKind],
    lines: usize,
    half: f32,
    rng: &mut ChaCha8Rng,
) -> Vec<(ShapeKind, Pose)> {
    const QUARTER: f32 = std::f32::consts::FRAC_PI_2;
    let faces_down = [
        Rotation::IDENTITY,
        Rotation::from_rotation_x(QUARTER),
        Rotation::from_rotation_x(-QUARTER),
        Rotation::from_rotation_x(2.0 * QUARTER),
        Rotation::from_rotation_y(QUARTER),
        Rotation::from_rotation_y(-QUARTER),
    ];
    // Each block in the row's frame (x along the row): its rotation and its box there.
    let blocks: Vec<(ShapeKind, Rotation, Vector, Vector)> = kinds
        .iter()
        .map(|&kind| {
            let stable: Vec<Rotation> = faces_down
                .iter()
                .copied()
                .filter(|&r| rests_flat(kind, r))
                .collect();
            let turn = Rotation::from_rotation_z(QUARTER * rng.random_range(0..4) as f32);
            let rotation = turn * stable[rng.random_range(0..stable.len())];
            let (lo, hi) = kind.bounds_turned(rotation);
            (kind, rotation, lo, hi)
        })
        .collect();
    let heading = Rotation::from_rotation_z(rng.random_range(0.0..TAU));
    let centre = Vector::new(
        workspace::CENTRE[0] + rng.random_range(-half / 2.0..half / 2.0),
        workspace::CENTRE[1] + rng.random_range(-half / 2.0..half / 2.0),
        0.0,
    );
    // Lines along x, stacked along y, the pack centred on `centre`, each line centred on its
    // own length. A lone line's blocks sit on its middle; in a pack the first line's lie
    // against the second and the others' against the line before, so the first two lines
    // touch wherever they face each other.
    let lines: Vec<_> = blocks.chunks(blocks.len().div_ceil(lines.max(1))).collect();
    let count = lines.len();
    let width = |line: &[(ShapeKind, Rotation, Vector, Vector)]| {
        line.iter()
            .map(|(_, _, lo, hi)| hi.y - lo.y)
            .fold(0.0, f32::max)
    };
    let pack_width: f32 = lines.iter().map(|l| width(l) + ROW_GAP).sum::<f32>() - ROW_GAP;
    let mut side = -pack_width / 2.0;
    let mut poses = Vec::with_capacity(blocks.len());
    for (index, line) in lines.into_iter().enumerate() {
        let start_y = side;
        side += width(line) + ROW_GAP;
        let length: f32 = line
            .iter()
            .map(|(_, _, lo, hi)| hi.x - lo.x + ROW_GAP)
            .sum();
        let mut start = -length / 2.0;
        for &(kind, rotation, lo, hi) in line {
            let y = match (index, count) {
                (_, 1) => -(lo.y + hi.y) / 2.0,
                (0, _) => side - ROW_GAP - hi.y,
                _ => start_y - lo.y,
            };
            let along = Vector::new(start - lo.x, y, 0.0);
            start += hi.x - lo.x + ROW_GAP;
            let position = centre + heading * along + Vector::new(0.0, 0.0, ROW_GAP - lo.z);
            poses.push((kind, Pose::from_parts(position, heading * rotation)));
        }
    }
    poses
}

/// Whether `kind` turned by `rotation` stands on a flat face: the vertices on its lowest
/// plane span at least a centimetre both ways, around the middle of its box (so no prism
/// rests on an edge, nor a cylinder on its side). Every shape rests flat on its base.
fn rests_flat(kind: ShapeKind, rotation: Rotation) -> bool {
    const ON_PLANE: f32 = 1e-3;
    const MIN_SPAN: f32 = 0.01;
    let (lo, hi) = kind.bounds_turned(rotation);
    let (foot_lo, foot_hi) = box_around(
        kind.vertices_turned(rotation)
            .filter(|v| v.z < lo.z + ON_PLANE),
    );
    let middle = (lo + hi) / 2.0;
    (foot_hi.x - foot_lo.x) >= MIN_SPAN
        && (foot_hi.y - foot_lo.y) >= MIN_SPAN
        && (foot_lo.x..=foot_hi.x).contains(&middle.x)
        && (foot_lo.y..=foot_hi.y).contains(&middle.y)
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
