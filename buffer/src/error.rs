//! What can go wrong in the buffer, one type per concern.

use std::path::PathBuf;

use experience::Key;
use sim::{ObjectId, Primitive};

use experience::CorruptObservation;

/// A request the replay cannot serve.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ReplayError {
    #[error("no {0:?} transitions to sample from")]
    Empty(Primitive),
    #[error("a batch needs at least one item")]
    EmptyBatch,
    #[error("priority {0} is not a finite number >= 0")]
    BadPriority(f64),
    #[error("the rate limiter holds sampling back: {samples} sampled for {inserts} inserted")]
    RateLimited { inserts: u64, samples: u64 },
    #[error("the observation of {key:?} is damaged: {why}")]
    Corrupt { key: Key, why: CorruptObservation },
}

/// An episode whose steps do not fit together.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum AssembleError {
    #[error("episode {0} has no steps")]
    UnknownEpisode(u64),
    #[error("step {step} of episode {episode} has priority {priority}, not a finite number >= 0")]
    BadPriority {
        episode: u64,
        step: u32,
        priority: f64,
    },
    #[error("episode {episode} received step {step} twice")]
    DuplicateStep { episode: u64, step: u32 },
    #[error("episode {episode} lacks step {missing}")]
    MissingStep { episode: u64, missing: u32 },
    #[error("episode {episode} ended with a grasp of object {object}, but no step grasped it")]
    GraspNotFound { episode: u64, object: ObjectId },
}

/// A snapshot that cannot be written or read; always names the file.
#[derive(Debug, thiserror::Error)]
#[error("buffer snapshot {}: {kind}", path.display())]
pub struct SnapshotError {
    pub path: PathBuf,
    pub kind: SnapshotErrorKind,
}

/// Why a snapshot failed.
#[derive(Debug, thiserror::Error)]
pub enum SnapshotErrorKind {
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("not a pushgrasp buffer snapshot (bad magic)")]
    BadMagic,
    #[error("format version {found}, this build reads {expected}")]
    Version { found: u32, expected: u32 },
    #[error("truncated or overlong: {found} bytes where the header promises {expected}")]
    Truncated { found: u64, expected: u64 },
    #[error("corrupted: checksum mismatch")]
    Checksum,
    #[error("cannot encode or decode: {0}")]
    Codec(#[from] postcard::Error),
    #[error("inconsistent contents: {0}")]
    Invalid(String),
}
