//! The top-down orthographic camera: colour, height and object-id heightmaps computed exactly
//! from the geometry.
//!
//! Each pixel is a vertical ray through its centre. For every convex part of every object the
//! ray meets the part between the highest of its lower bounding planes and the lowest of its
//! upper ones; the highest top over all parts wins the pixel. Only pixels under a part's
//! footprint are visited; the footprint and the ray's top are `footprint`'s, shared with the
//! tabletop's view tests. (parry's ray casts on hulls give false hits up to 2 cm outside the
//! shape, and casting every pixel against the scene is an order of magnitude slower.)

use serde::de::Error;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::footprint;
use crate::tabletop::{ObjectId, Tabletop};
use crate::workspace::PixelGrid;

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
            footprint::covered_pixels(
                object.kind,
                &object.pose,
                grid,
                &mut planes,
                |row, col, top| {
                    let i = row * side + col;
                    if top > maps.height[i] {
                        maps.height[i] = top;
                        maps.ids[i] = object.id;
                        maps.colour[i] = object.colour;
                    }
                    true
                },
            );
        }
    }
}
