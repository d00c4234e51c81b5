//! Scene measurements the rewards need, as the paper defines them at 2 mm pixels and scaled
//! to the grid's pixel size: the occupancy ratio of the ring around the goal (and the object
//! whose ring is most occupied), change detection around the goal after a push, and whether
//! a push moved anything at all.

use image::{GrayImage, Luma};
use imageproc::distance_transform::Norm;
use imageproc::point::Point;

use crate::camera::Heightmaps;
use crate::tabletop::ObjectId;

/// Width of the ring around the goal, in 2 mm pixels (10 dilations).
const RING_WIDTH_REF: f32 = 10.0;
/// Heights that count as occupying the ring (metres).
const OCCUPIED_BAND: (f32, f32) = (0.02, 0.3);
/// Height decreases that count as a change (metres).
const DECREASE_BAND: (f32, f32) = (0.01, 0.3);
/// Changed pixels needed, in 2 mm pixels (scaled by area).
const CHANGED_PIXELS_REF: f32 = 50.0;
/// The occupancy ratio must fall by more than this.
const OCCUPANCY_DROP: f32 = 0.1;

/// What change detection found between two observations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChangeReport {
    /// Pixels in the dilated hull of the goal whose height fell within the band.
    pub changed_pixels: usize,
    /// The threshold those pixels had to exceed at this pixel size.
    pub changed_pixels_needed: usize,
    pub occupancy_before: f32,
    pub occupancy_after: f32,
    /// Both: enough pixels changed, and the occupancy fell by more than 0.1.
    pub detected: bool,
}

/// Ring width in pixels of this grid.
fn ring_width(maps: &Heightmaps) -> u8 {
    (RING_WIDTH_REF * maps.grid.scale())
        .round()
        .clamp(1.0, 255.0) as u8
}

fn mask_image(maps: &Heightmaps, goal: ObjectId) -> GrayImage {
    let side = maps.side() as u32;
    let pixels = maps
        .goal_mask(goal)
        .iter()
        .map(|&m| if m { 255 } else { 0 })
        .collect();
    GrayImage::from_raw(side, side, pixels).expect("mask has side * side pixels")
}

/// Fraction of the ring around the goal mask (its dilation minus the mask) whose height lies
/// in [0.02, 0.3] m. A goal not seen from above counts as fully surrounded (1.0).
pub fn occupancy_ratio(maps: &Heightmaps, goal: ObjectId) -> f32 {
    let mask = mask_image(maps, goal);
    let dilated = imageproc::morphology::dilate(&mask, Norm::LInf, ring_width(maps));
    let (mut ring, mut occupied) = (0usize, 0usize);
    for (i, (m, d)) in mask.iter().zip(dilated.iter()).enumerate() {
        if *d > 0 && *m == 0 {
            ring += 1;
            let h = maps.height[i];
            occupied += usize::from((OCCUPIED_BAND.0..=OCCUPIED_BAND.1).contains(&h));
        }
    }
    if ring == 0 {
        1.0
    } else {
        occupied as f32 / ring as f32
    }
}

/// Of the objects `among` (seen in `maps`), the one whose ring is most occupied
/// ([`occupancy_ratio`]); the highest id among equals, `None` when `among` is empty.
pub fn most_crowded(maps: &Heightmaps, among: &[ObjectId]) -> Option<ObjectId> {
    among
        .iter()
        .map(|&id| (occupancy_ratio(maps, id), id))
        .max_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
        .map(|(_, id)| id)
}

/// The goal's convex hull in `maps`, filled and dilated by the ring width.
fn dilated_hull(maps: &Heightmaps, goal: ObjectId) -> GrayImage {
    let side = maps.side() as u32;
    let points: Vec<Point<i32>> = maps
        .goal_mask(goal)
        .iter()
        .enumerate()
        .filter(|(_, m)| **m)
        .map(|(i, _)| Point::new((i % side as usize) as i32, (i / side as usize) as i32))
        .collect();
    let mut hull_image = GrayImage::new(side, side);
    let hull = imageproc::geometry::convex_hull(points);
    if hull.len() >= 3 {
        imageproc::drawing::draw_polygon_mut(&mut hull_image, &hull, Luma([255]));
    }
    for p in &hull {
        hull_image.put_pixel(p.x as u32, p.y as u32, Luma([255]));
    }
    imageproc::morphology::dilate(&hull_image, Norm::LInf, ring_width(maps))
}

/// Change detection around the goal between the observation before a push and the one after.
pub fn detect_change(before: &Heightmaps, after: &Heightmaps, goal: ObjectId) -> ChangeReport {
    let region = dilated_hull(before, goal);
    let changed_pixels = region
        .iter()
        .zip(before.height.iter().zip(&after.height))
        .filter(|(r, (b, a))| **r > 0 && (DECREASE_BAND.0..=DECREASE_BAND.1).contains(&(*b - *a)))
        .count();
    let changed_pixels_needed = changed_pixels_needed(before);
    let occupancy_before = occupancy_ratio(before, goal);
    let occupancy_after = occupancy_ratio(after, goal);
    ChangeReport {
        changed_pixels,
        changed_pixels_needed,
        occupancy_before,
        occupancy_after,
        detected: changed_pixels > changed_pixels_needed
            && occupancy_before - occupancy_after > OCCUPANCY_DROP,
    }
}

/// Whether anything moved between two observations: more pixels anywhere than change
/// detection needs around the goal whose height rose or fell by at least its centimetre.
/// A push that moved nothing leaves the scene as it was.
pub fn scene_changed(before: &Heightmaps, after: &Heightmaps) -> bool {
    let changed_pixels = before
        .height
        .iter()
        .zip(&after.height)
        .filter(|(b, a)| (*b - *a).abs() >= DECREASE_BAND.0)
        .count();
    changed_pixels > changed_pixels_needed(before)
}

/// The changed pixels a change needs at this grid's pixel size (50 at 2 mm, scaled by area).
fn changed_pixels_needed(maps: &Heightmaps) -> usize {
    let scale = maps.grid.scale();
    (CHANGED_PIXELS_REF * scale * scale).round() as usize
}
