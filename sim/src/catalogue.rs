//! The object catalogue: the eight toy-block shapes of the original set, their convex parts,
//! their material, and the ten slot colours.
//!
//! Each shape's body frame is the one the original test-case files pose: the origin at the
//! centre of the shape's bounding box, and for every mesh but `2.obj` and `6.obj` the mesh's
//! upright axis along body x (the original simulator shapes are the meshes rotated by
//! R = `[[0,0,1],[0,-1,0],[1,0,0]]`). So `0.obj` (the roof) rests on its base when body -x
//! points down. These frames were fixed by checking that every object in the original files
//! rests flat on the table (see the arrangement tests).

use std::f32::consts::PI;
use std::sync::OnceLock;

use rapier3d::parry::shape::ConvexPolyhedron;
use rapier3d::prelude::{Rotation, Vector};
use serde::{Deserialize, Serialize};

/// The original set's colours by slot (RGB 0-255): blue, green, brown, orange, yellow, gray,
/// red, purple, cyan, pink.
pub const SLOT_COLOURS: [[u8; 3]; 10] = [
    [78, 121, 167],
    [89, 161, 79],
    [156, 117, 95],
    [242, 142, 43],
    [237, 201, 72],
    [186, 176, 172],
    [255, 87, 89],
    [176, 122, 161],
    [118, 183, 178],
    [255, 157, 167],
];

/// The lowest and highest corner of the axis-aligned box around `points`.
pub(crate) fn box_around(points: impl Iterator<Item = Vector>) -> (Vector, Vector) {
    points.fold(
        (
            Vector::splat(f32::INFINITY),
            Vector::splat(f32::NEG_INFINITY),
        ),
        |(lo, hi), v| (lo.min(v), hi.max(v)),
    )
}

/// The eight shapes, named by what they are; `mesh_name` gives the original file name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ShapeKind {
    /// `0.obj`: triangular prism, base 0.093, apex height 0.049, depth 0.05.
    Roof,
    /// `1.obj`: 0.10 x 0.05 x 0.05 block with a half-cylinder tunnel of radius 0.025.
    Arch,
    /// `2.obj`: 0.05 x 0.05 x 0.025 slab with chamfered edges (0.043 flat faces).
    Slab,
    /// `3.obj`: flat bar 0.10 x 0.05 x 0.025.
    Bar,
    /// `4.obj`: cube 0.05.
    Cube,
    /// `6.obj`: tall block 0.05 x 0.05 x 0.10.
    TallBlock,
    /// `7.obj`: half-cylinder, radius 0.025, length 0.05.
    HalfCylinder,
    /// `8.obj`: cylinder, diameter 0.045, height 0.05 (a 16-sided prism: exact cylinders
    /// roll and never settle in rapier).
    Cylinder,
}

impl ShapeKind {
    pub const ALL: [ShapeKind; 8] = [
        ShapeKind::Roof,
        ShapeKind::Arch,
        ShapeKind::Slab,
        ShapeKind::Bar,
        ShapeKind::Cube,
        ShapeKind::TallBlock,
        ShapeKind::HalfCylinder,
        ShapeKind::Cylinder,
    ];

    /// The original mesh file this shape stands for.
    pub fn mesh_name(self) -> &'static str {
        match self {
            ShapeKind::Roof => "0.obj",
            ShapeKind::Arch => "1.obj",
            ShapeKind::Slab => "2.obj",
            ShapeKind::Bar => "3.obj",
            ShapeKind::Cube => "4.obj",
            ShapeKind::TallBlock => "6.obj",
            ShapeKind::HalfCylinder => "7.obj",
            ShapeKind::Cylinder => "8.obj",
        }
    }

    pub fn from_mesh_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.mesh_name() == name)
    }

    /// The name used in our own files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ShapeKind::Roof => "roof",
            ShapeKind::Arch => "arch",
            ShapeKind::Slab => "slab",
            ShapeKind::Bar => "bar",
            ShapeKind::Cube => "cube",
            ShapeKind::TallBlock => "tall-block",
            ShapeKind::HalfCylinder => "half-cylinder",
            ShapeKind::Cylinder => "cylinder",
        }
    }

    /// The box around the shape in its body frame: its lowest and highest corner.
    pub fn bounds(self) -> (Vector, Vector) {
        self.bounds_turned(Rotation::IDENTITY)
    }

    /// The axis-aligned box around the shape turned by `rotation` about its origin.
    pub fn bounds_turned(self, rotation: Rotation) -> (Vector, Vector) {
        box_around(self.vertices_turned(rotation))
    }

    /// Every vertex of the shape's parts, turned by `rotation` about its origin.
    pub fn vertices_turned(self, rotation: Rotation) -> impl Iterator<Item = Vector> {
        self.parts()
            .iter()
            .flat_map(|p| p.vertices.iter())
            .map(move |&v| rotation * v)
    }

    /// The shape's convex parts in its body frame (built once, shared).
    pub fn parts(self) -> &'static [ConvexPart] {
        static PARTS: OnceLock<Vec<Vec<ConvexPart>>> = OnceLock::new();
        let all = PARTS.get_or_init(|| {
            Self::ALL
                .iter()
                .map(|k| k.part_points().iter().map(|p| ConvexPart::new(p)).collect())
                .collect()
        });
        &all[self as usize]
    }

    /// Vertices of each convex part, in the body frame.
    fn part_points(self) -> Vec<Vec<Vector>> {
        match self {
            ShapeKind::Roof => {
                // Pentagonal profile in (x up, z across): 2.5 mm walls, then 45 degree slopes.
                let profile = [
                    (-0.0245, -0.0465),
                    (-0.0220, -0.0465),
                    (0.0245, 0.0),
                    (-0.0220, 0.0465),
                    (-0.0245, 0.0465),
                ];
                vec![extrude_xz(&profile, 0.025)]
            }
            ShapeKind::Arch => arch_parts(),
            ShapeKind::Slab => {
                let (h, c) = (0.025, 0.0035);
                let profile = [
                    (h, h - c),
                    (h - c, h),
                    (c - h, h),
                    (-h, h - c),
                    (-h, c - h),
                    (c - h, -h),
                    (h - c, -h),
                    (h, c - h),
                ];
                vec![extrude_yz(&profile, 0.0125)]
            }
            ShapeKind::Bar => vec![cuboid(0.0125, 0.025, 0.05)],
            ShapeKind::Cube => vec![cuboid(0.025, 0.025, 0.025)],
            ShapeKind::TallBlock => vec![cuboid(0.025, 0.025, 0.05)],
            ShapeKind::HalfCylinder => {
                // Flat face at x = -0.0125, the round side up to x = +0.0125; axis along z.
                let r = 0.025;
                let profile: Vec<(f32, f32)> = (0..=8)
                    .map(|i| {
                        let a = -PI / 2.0 + i as f32 * PI / 8.0;
                        (-0.0125 + r * a.cos(), r * a.sin())
                    })
                    .collect();
                let mut points = Vec::new();
                for z in [-0.025, 0.025] {
                    points.extend(profile.iter().map(|&(x, y)| Vector::new(x, y, z)));
                }
                vec![points]
            }
            ShapeKind::Cylinder => {
                let r = 0.0225;
                let profile: Vec<(f32, f32)> = (0..16)
                    .map(|i| {
                        let a = i as f32 * PI / 8.0;
                        (r * a.cos(), r * a.sin())
                    })
                    .collect();
                vec![extrude_yz(&profile, 0.025)]
            }
        }
    }
}

/// The arch: two legs and six strips over the tunnel, whose ceiling is the arc of radius
/// 0.025 centred on the bottom face (body x up, z along the arch).
fn arch_parts() -> Vec<Vec<Vector>> {
    let (hx, hy, r) = (0.025, 0.025, 0.025);
    let mut parts = vec![
        box_between([-hx, -hy, -0.05], [hx, hy, -r]),
        box_between([-hx, -hy, r], [hx, hy, 0.05]),
    ];
    let strips = 6;
    let ceiling = |z: f32| -hx + (r * r - z * z).max(0.0).sqrt();
    for i in 0..strips {
        let z0 = -r + 2.0 * r * i as f32 / strips as f32;
        let z1 = -r + 2.0 * r * (i + 1) as f32 / strips as f32;
        let profile = [(ceiling(z0), z0), (ceiling(z1), z1), (hx, z1), (hx, z0)];
        parts.push(extrude_xz(&profile, hy));
    }
    parts
}

fn cuboid(hx: f32, hy: f32, hz: f32) -> Vec<Vector> {
    box_between([-hx, -hy, -hz], [hx, hy, hz])
}

fn box_between(lo: [f32; 3], hi: [f32; 3]) -> Vec<Vector> {
    let mut points = Vec::with_capacity(8);
    for x in [lo[0], hi[0]] {
        for y in [lo[1], hi[1]] {
            for z in [lo[2], hi[2]] {
                points.push(Vector::new(x, y, z));
            }
        }
    }
    points
}

/// A profile in the (x, z) plane extruded along y by +-half_depth.
fn extrude_xz(profile: &[(f32, f32)], half_depth: f32) -> Vec<Vector> {
    [-half_depth, half_depth]
        .iter()
        .flat_map(|&y| profile.iter().map(move |&(x, z)| Vector::new(x, y, z)))
        .collect()
}

/// A profile in the (y, z) plane extruded along x by +-half_depth.
fn extrude_yz(profile: &[(f32, f32)], half_depth: f32) -> Vec<Vector> {
    [-half_depth, half_depth]
        .iter()
        .flat_map(|&x| profile.iter().map(move |&(y, z)| Vector::new(x, y, z)))
        .collect()
}

/// One convex piece of a shape: its vertices, and its faces as half-spaces n . p <= d, which
/// the camera intersects with vertical rays exactly.
#[derive(Clone, Debug)]
pub struct ConvexPart {
    pub vertices: Vec<Vector>,
    pub planes: Vec<(Vector, f32)>,
}

impl ConvexPart {
    fn new(points: &[Vector]) -> Self {
        let hull = ConvexPolyhedron::from_convex_hull(points)
            .expect("catalogue shapes are non-degenerate");
        let adjacent = hull.vertices_adj_to_face();
        let planes = hull
            .faces()
            .iter()
            .map(|face| {
                let on_face = hull.points()[adjacent[face.first_vertex_or_edge as usize] as usize];
                (face.normal, face.normal.dot(on_face))
            })
            .collect();
        Self {
            vertices: hull.points().to_vec(),
            planes,
        }
    }
}
