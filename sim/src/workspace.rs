//! The workspace bounds and the pixel grid the camera and the primitives share.

use crate::error::SimError;

/// Workspace bounds in the original world frame (metres).
pub const X_MIN: f32 = -0.724;
pub const X_MAX: f32 = -0.276;
pub const Y_MIN: f32 = -0.224;
pub const Y_MAX: f32 = 0.224;
/// Side of the square workspace.
pub const SIDE: f32 = 0.448;
/// The centre of the workspace, where random drops are centred.
pub const CENTRE: [f32; 2] = [(X_MIN + X_MAX) / 2.0, (Y_MIN + Y_MAX) / 2.0];

/// The pixel size the paper's numbers are stated at; pixel-count thresholds scale from it.
pub const REFERENCE_PIXEL_SIZE: f32 = 0.002;

/// A square grid of pixels over the workspace: row r covers y from `Y_MIN + r * size`,
/// column c covers x from `X_MIN + c * size`.
///
/// A pixel's world point is its centre (the original uses its corner, half a pixel away; the
/// centre keeps the camera and the primitives exactly consistent).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "f32", into = "f32")]
pub struct PixelGrid {
    pixel_size: f32,
    side: usize,
}

/// A grid is written as its pixel size.
impl From<PixelGrid> for f32 {
    fn from(grid: PixelGrid) -> f32 {
        grid.pixel_size
    }
}

impl TryFrom<f32> for PixelGrid {
    type Error = SimError;

    fn try_from(pixel_size: f32) -> Result<Self, SimError> {
        Self::new(pixel_size)
    }
}

impl PixelGrid {
    /// A grid with the given pixel size in metres; the workspace side must be a whole number
    /// of pixels (2 mm -> 224, 4 mm -> 112).
    pub fn new(pixel_size: f32) -> Result<Self, SimError> {
        let pixels = SIDE / pixel_size;
        let side = pixels.round();
        if !pixel_size.is_finite()
            || pixel_size <= 0.0
            || side < 8.0
            || (pixels - side).abs() > 1e-3
        {
            return Err(SimError::PixelSize(pixel_size));
        }
        Ok(Self {
            pixel_size,
            side: side as usize,
        })
    }

    pub fn pixel_size(&self) -> f32 {
        self.pixel_size
    }

    /// Pixels per side (the heightmap is `side x side`).
    pub fn side(&self) -> usize {
        self.side
    }

    pub fn len(&self) -> usize {
        self.side * self.side
    }

    pub fn is_empty(&self) -> bool {
        self.side == 0
    }

    /// The world (x, y) of a pixel's centre.
    pub fn pixel_centre(&self, row: usize, col: usize) -> [f32; 2] {
        [
            X_MIN + (col as f32 + 0.5) * self.pixel_size,
            Y_MIN + (row as f32 + 0.5) * self.pixel_size,
        ]
    }

    /// The (row, col) of the pixel holding a world point, if it lies in the workspace.
    pub fn pixel_of(&self, x: f32, y: f32) -> Option<(usize, usize)> {
        let col = ((x - X_MIN) / self.pixel_size).floor();
        let row = ((y - Y_MIN) / self.pixel_size).floor();
        let n = self.side as f32;
        (col >= 0.0 && row >= 0.0 && col < n && row < n).then_some((row as usize, col as usize))
    }

    /// The grid `factor` times finer, on the same workspace: each of this grid's pixels
    /// splits into `factor x factor`, and for an odd `factor` its centre is the centre of
    /// the middle one.
    pub fn finer(&self, factor: usize) -> Result<Self, SimError> {
        Self::new(self.pixel_size / factor as f32)
    }

    /// How many pixels of this grid span one reference (2 mm) pixel: pixel-count thresholds
    /// and window sizes stated at 2 mm scale by this factor (areas by its square).
    pub fn scale(&self) -> f32 {
        REFERENCE_PIXEL_SIZE / self.pixel_size
    }
}

/// Whether a world point lies over the workspace, the part of the table the camera sees.
pub fn contains(x: f32, y: f32) -> bool {
    (X_MIN..=X_MAX).contains(&x) && (Y_MIN..=Y_MAX).contains(&y)
}

/// How far a world point lies inside the workspace's nearest edge (metres); negative past it.
pub fn inside_by(x: f32, y: f32) -> f32 {
    (x - X_MIN).min(X_MAX - x).min(y - Y_MIN).min(Y_MAX - y)
}
