//! The crate's error type.

use std::path::PathBuf;

use thiserror::Error;

/// Why a sweep could not be loaded, rendered or followed.
///
/// Underlying errors are part of the message rather than a `source`: toml's carries the line
/// and column, and printing it twice in an error chain would only add noise.
#[derive(Debug, Error)]
pub enum SweepError {
    /// The sweep file could not be read.
    #[error("cannot read sweep file {}: {cause}", path.display())]
    Read {
        path: PathBuf,
        cause: std::io::Error,
    },
    /// The sweep file is not valid TOML or does not have the sweep file's shape.
    #[error("cannot parse sweep file {}: {cause}", path.display())]
    Parse {
        path: PathBuf,
        cause: Box<toml::de::Error>,
    },
    /// The base config the sweep file names could not be read.
    #[error("{}: cannot read base config {}: {cause}", sweep.display(), base.display())]
    ReadBase {
        sweep: PathBuf,
        base: PathBuf,
        cause: std::io::Error,
    },
    /// The base config the sweep file names is not valid TOML.
    #[error("{}: cannot parse base config {}: {cause}", sweep.display(), base.display())]
    ParseBase {
        sweep: PathBuf,
        base: PathBuf,
        cause: Box<toml::de::Error>,
    },
    /// One `[[axis]]` is invalid; `number` counts from 1 in file order.
    #[error("{}: [[axis]] number {number} ({key}): {message}", path.display())]
    Axis {
        path: PathBuf,
        number: usize,
        key: String,
        message: String,
    },
    /// Something else in the sweep file is invalid (its name, budget or `[slurm]` section).
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    /// The Slurm script cannot be rendered for these runs.
    #[error("cannot render the Slurm script: {0}")]
    Script(String),
    /// A line of `sacct` or `squeue` output could not be understood.
    #[error("line {line} of Slurm's output ({text:?}): {message}")]
    SlurmOutput {
        line: usize,
        text: String,
        message: String,
    },
}
