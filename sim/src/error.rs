//! Errors the tabletop reports, each naming what was wrong and where, and the one every
//! part of pushgrasp gives for a config value it cannot use.

use std::fmt::Display;
use std::ops::{Bound, RangeBounds};
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

/// The numbers above `low`, for [`ConfigError::check_range`].
pub fn above<T>(low: T) -> (Bound<T>, Bound<T>) {
    (Bound::Excluded(low), Bound::Unbounded)
}

/// A config field whose value its part cannot use. Every part's config names its fields
/// within its own table; the run config puts the table in front (`gamma` becomes
/// `learning.gamma`).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{field}: {why}")]
pub struct ConfigError {
    pub field: String,
    pub why: String,
}

impl ConfigError {
    pub fn new(field: impl Into<String>, why: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            why: why.into(),
        }
    }

    /// The same error, its field named from the enclosing `table`.
    pub fn in_table(self, table: &str) -> Self {
        Self {
            field: format!("{table}.{}", self.field),
            ..self
        }
    }

    /// `Ok` when `value` is a finite number within `range`, else an error naming `field`.
    pub fn check_range<T: Copy + Display + PartialOrd + Into<f64>>(
        field: &str,
        value: T,
        range: impl RangeBounds<T>,
    ) -> Result<(), Self> {
        if value.into().is_finite() && range.contains(&value) {
            return Ok(());
        }
        let wanted = match (range.start_bound(), range.end_bound()) {
            (Bound::Included(low), Bound::Unbounded) => format!(">= {low}"),
            (Bound::Excluded(low), Bound::Unbounded) => format!("> {low}"),
            (Bound::Unbounded, Bound::Unbounded) => String::new(),
            (low, high) => {
                let (open, low) = match low {
                    Bound::Included(low) => ('[', low.to_string()),
                    Bound::Excluded(low) => ('(', low.to_string()),
                    Bound::Unbounded => ('(', "-inf".to_string()),
                };
                let (high, close) = match high {
                    Bound::Included(high) => (high.to_string(), ']'),
                    Bound::Excluded(high) => (high.to_string(), ')'),
                    Bound::Unbounded => ("inf".to_string(), ')'),
                };
                format!("in {open}{low}, {high}{close}")
            }
        };
        let why = format!("{value} is not a finite number {wanted}");
        Err(Self::new(field, why.trim_end()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_range_check_says_which_numbers_the_field_takes() {
        let why = |result: Result<(), ConfigError>| result.unwrap_err().to_string();
        assert_eq!(
            why(ConfigError::check_range("gamma", 1.0f32, 0.0..1.0)),
            "gamma: 1 is not a finite number in [0, 1)"
        );
        assert_eq!(
            why(ConfigError::check_range("lr", 0.0, above(0.0))),
            "lr: 0 is not a finite number > 0"
        );
        assert_eq!(
            why(ConfigError::check_range("alpha", -0.5, 0.0..)),
            "alpha: -0.5 is not a finite number >= 0"
        );
        assert_eq!(
            why(ConfigError::check_range("q", f32::NAN, ..)),
            "q: NaN is not a finite number"
        );
        assert_eq!(
            why(ConfigError::check_range("e", f64::INFINITY, 0.0..=1.0)),
            "e: inf is not a finite number in [0, 1]"
        );
        ConfigError::check_range("gamma", 0.0f32, 0.0..1.0).unwrap();
        ConfigError::check_range("q", -1e30f32, ..).unwrap();
        assert_eq!(
            ConfigError::new("gamma", "no")
                .in_table("learning")
                .to_string(),
            "learning.gamma: no"
        );
    }
}
