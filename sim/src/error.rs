//! Errors the tabletop reports, each naming what was wrong and where.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error(
        "pixel size {0} m does not divide the 0.448 m workspace into a whole number of pixels (at least 8)"
    )]
    PixelSize(f32),
    #[error("rotation index {0} is out of range (0..16)")]
    Rotation(u8),
    #[error("pixel ({row}, {col}) is outside the {side} x {side} heightmap")]
    Pixel { row: usize, col: usize, side: usize },
    #[error("heightmaps were rendered at {got} x {got} but the tabletop's grid is {want} x {want}")]
    GridMismatch { got: usize, want: usize },
    #[error("too many objects: {0} (object ids are 1..=255)")]
    TooManyObjects(usize),
    #[error("object id {0} is taken or reserved (0 is the table)")]
    ObjectId(u8),
    #[error(transparent)]
    Arrangement(#[from] ArrangementError),
}

/// A malformed or unreadable arrangement file; always names the file, and the line where
/// there is one.
#[derive(Debug, thiserror::Error)]
pub enum ArrangementError {
    #[error("{path}: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Line {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
}
