//! Where an object lies over the camera's pixel grid: the pixels whose centre's vertical
//! line meets it, and the height where that line leaves it at the top. The camera renders
//! from it; the tabletop asks it whether an object is still in view.

use rapier3d::prelude::{Pose, Vector};

use crate::catalogue::ShapeKind;
use crate::workspace::{self, PixelGrid};

/// Whether any of the object of `kind` at `pose` lies over a pixel centre of `grid`, seen or
/// hidden under another: an object the camera could see, were it on top.
pub(crate) fn in_view(kind: ShapeKind, pose: &Pose, grid: PixelGrid) -> bool {
    let mut seen = false;
    covered_pixels(kind, pose, grid, &mut Vec::new(), |_, _, _| {
        seen = true;
        false
    });
    seen
}

/// Calls `visit(row, col, top)` for every pixel of `grid` whose centre's vertical line meets
/// the object of `kind` at `pose`, with the height where it leaves the object's part at the
/// top, part by part, until `visit` returns false. `planes` is scratch space, kept from call
/// to call.
pub(crate) fn covered_pixels(
    kind: ShapeKind,
    pose: &Pose,
    grid: PixelGrid,
    planes: &mut Vec<(Vector, f32)>,
    mut visit: impl FnMut(usize, usize, f32) -> bool,
) {
    let (side, size) = (grid.side(), grid.pixel_size());
    for part in kind.parts() {
        let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
        for v in &part.vertices {
            let w = pose.transform_point(*v);
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
            let n = pose.rotation * n;
            (n, d + n.dot(pose.translation))
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
fn ray_top(planes: &[(Vector, f32)], x: f32, y: f32) -> Option<f32> {
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
