//! The top-down orthographic camera: colour, height and object-id heightmaps computed exactly
//! from the geometry.
//!
//! Each pixel is a vertical ray through its centre. For every convex part of every object the
//! ray meets the part between the highest of its lower bounding planes and the lowest of its
//! upper ones; the highest top over all parts wins the pixel. Only pixels under a part's
//! footprint are visited. (parry's ray casts on hulls give false hits up to 2 cm outside the
//! shape, and casting every pixel against the scene is an order of magnitude slower.)

use serde::de::Error;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::tabletop::{ObjectId, ObjectView, Tabletop};
use crate::workspace::{self, PixelGrid};

/// Colour of the bare table in the colour heightmap.
pub const TABLE_COLOUR: [u8; 3] = [0, 0, 0];

/// What the camera sees: three row-major `side x side` maps over the workspace.
#[derive(Clone, Debug, PartialEq)]
pub struct Heightmaps {
    pub grid: PixelGrid,
    /// RGB of the highest surface at each pixel.
    pub colour: Vec<[u8; 3]>,
    /// Height of the highest surface above the table (metres, >= 0).
    pub height: Vec<f32>,
    /// Id of the object owning the highest surface, 0 for the table.
    pub ids: Vec<ObjectId>,
}

impl Heightmaps {
    /// Empty maps (bare table) on a grid.
    pub fn new(grid: PixelGrid) -> Self {
        Self {
            grid,
            colour: vec![TABLE_COLOUR; grid.len()],
            height: vec![0.0; grid.len()],
            ids: vec![0; grid.len()],
        }
    }

    pub fn side(&self) -> usize {
        self.grid.side()
    }

    pub fn index(&self, row: usize, col: usize) -> usize {
        row * self.grid.side() + col
    }

    /// The goal mask: 1 where the goal object is the highest surface, else 0; for
    /// [`ANY_OBJECT`](crate::ANY_OBJECT), 1 wherever an object is.
    pub fn goal_mask(&self, goal: ObjectId) -> Vec<bool> {
        self.ids
            .iter()
            .map(|&id| id != 0 && (id == goal || goal == crate::ANY_OBJECT))
            .collect()
    }

    /// The ids seen from above, in increasing order.
    pub fn visible_ids(&self) -> Vec<ObjectId> {
        let mut seen = [false; 256];
        for &id in &self.ids {
            seen[id as usize] = true;
        }
        (1..=255u8).filter(|&id| seen[id as usize]).collect()
    }
}

/// Heightmaps travel (replay, snapshots, messages) as their pixel size and three maps, and
/// are checked on the way back in: the pixel size must make a grid and the maps its size.
#[derive(Serialize)]
struct HeightmapsRef<'a> {
    pixel_size: f32,
    colour: &'a [[u8; 3]],
    height: &'a [f32],
    ids: &'a [ObjectId],
}

#[derive(Deserialize)]
struct HeightmapsData {
    pixel_size: f32,
    colour: Vec<[u8; 3]>,
    height: Vec<f32>,
    ids: Vec<ObjectId>,
}

impl Serialize for Heightmaps {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        HeightmapsRef {
            pixel_size: self.grid.pixel_size(),
            colour: &self.colour,
            height: &self.height,
            ids: &self.ids,
        }
        .serialize(serializer)
    }
}

impl<'de> Deserialize<'de> for Heightmaps {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let data = HeightmapsData::deserialize(deserializer)?;
        let grid = PixelGrid::new(data.pixel_size).map_err(D::Error::custom)?;
        let n = grid.len();
        if data.colour.len() != n || data.height.len() != n || data.ids.len() != n {
            return Err(D::Error::custom(format!(
                "heightmaps of {} colour, {} height and {} id pixels on a grid of {n}",
                data.colour.len(),
                data.height.len(),
                data.ids.len()
            )));
        }
        Ok(Self {
            grid,
            colour: data.colour,
            height: data.height,
            ids: data.ids,
        })
    }
}

/// Renders heightmaps of a tabletop on a pixel grid.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    grid: PixelGrid,
}

impl Camera {
    pub fn new(grid: PixelGrid) -> Self {
        Self { grid }
    }

    pub fn grid(&self) -> PixelGrid {
        self.grid
    }

    pub fn render(&self, tabletop: &Tabletop) -> Heightmaps {
        let mut maps = Heightmaps::new(self.grid);
        self.render_into(tabletop, &mut maps);
        maps
    }

    /// Renders into existing maps, reusing their memory.
    pub fn render_into(&self, tabletop: &Tabletop, maps: &mut Heightmaps) {
        let grid = self.grid;
        let side = grid.side();
        maps.grid = grid;
        maps.colour.clear();
        maps.colour.resize(grid.len(), TABLE_COLOUR);
        maps.height.clear();
        maps.height.resize(grid.len(), 0.0);
        maps.ids.clear();
        maps.ids.resize(grid.len(), 0);
        // Tops of the table itself count as height 0, so a surface must rise above it.
        let mut planes = Vec::new();
        for object in tabletop.objects() {
            covered_pixels(&object, grid, &mut planes, |row, col, top| {
                let i = row * side + col;
                if top > maps.height[i] {
                    maps.height[i] = top;
                    maps.ids[i] = object.id;
                    maps.colour[i] = object.colour;
                }
                true
            });
        }
    }
}

/// Whether any of the object lies over a pixel centre of `grid`, seen or hidden under
/// another: an object the camera could see, were it on top.
pub(crate) fn in_view(object: &ObjectView, grid: PixelGrid) -> bool {
    let mut seen = false;
    covered_pixels(object, grid, &mut Vec::new(), |_, _, _| {
        seen = true;
        false
    });
    seen
}

/// Calls `visit(row, col, top)` for every pixel of `grid` whose centre's vertical line meets
/// the object, with the height where it leaves the object's part at the top, part by part,
/// until `visit` returns false. `planes` is scratch space, kept from call to call.
fn covered_pixels(
    object: &ObjectView,
    grid: PixelGrid,
    planes: &mut Vec<(rapier3d::prelude::Vector, f32)>,
    mut visit: impl FnMut(usize, usize, f32) -> bool,
) {
    let (side, size) = (grid.side(), grid.pixel_size());
    for part in object.kind.parts() {
        let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
        for v in &part.vertices {
            let w = object.pose.transform_point(*v);
            lo = [lo[0].min(w.x), lo[1].min(w.y)];
            hi = [hi[0].max(w.x), hi[1].max(w.y)];
        }
        let col0 = ((lo[0] - workspace::X_MIN) / size - 0.5).ceil().max(0.0) as usize;
        let row0 = ((lo[1] - workspace::Y_MIN) / size - 0.5).ceil().max(0.0) as usize;
        let col1 = ((hi[0] - workspace::X_MIN) / size - 0.5).floor();
        let row1 = ((hi[1] - workspace::Y_MIN) / size - 0.5).floor();
        if col1 < 0.0 || row1 < 0.0 {
            continue;
        }
        let col1 = (col1 as usize).min(side - 1);
        let row1 = (row1 as usize).min(side - 1);
        planes.clear();
        planes.extend(part.planes.iter().map(|&(n, d)| {
            let n = object.pose.rotation * n;
            (n, d + n.dot(object.pose.translation))
        }));
        for row in row0..=row1 {
            for col in col0..=col1 {
                let [x, y] = grid.pixel_centre(row, col);
                if let Some(top) = ray_top(planes, x, y)
                    && !visit(row, col, top)
                {
                    return;
                }
            }
        }
    }
}

/// Where a vertical line at (x, y) leaves the convex region { p : n . p <= d } at the top,
/// if it passes through it.
fn ray_top(planes: &[(rapier3d::prelude::Vector, f32)], x: f32, y: f32) -> Option<f32> {
    let (mut top, mut bottom) = (f32::MAX, f32::MIN);
    for &(n, d) in planes {
        let rhs = d - n.x * x - n.y * y;
        if n.z > 1e-6 {
            top = top.min(rhs / n.z);
        } else if n.z < -1e-6 {
            bottom = bottom.max(rhs / n.z);
        } else if rhs < 0.0 {
            return None;
        }
    }
    (top >= bottom).then_some(top)
}
