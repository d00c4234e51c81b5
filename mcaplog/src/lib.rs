//! The run log: every pushgrasp process (launcher, buffer, learner, each actor) writes one MCAP
//! file into `logs/<run-id>/`, and this crate writes and reads those files.
//!
//! - Writing ([`RunLog`]): metadata records (the resolved config, the process), our own metrics
//!   as JSON messages with a `jsonschema` schema; images as `foxglove.RawImage` or
//!   `foxglove.CompressedImage`, scenes as `foxglove.SceneUpdate` and log lines as
//!   `foxglove.Log`, all in protobuf encoding with the `FileDescriptorSet` as schema, so
//!   Foxglove, Rerun and the generic `mcap` readers decode everything. Chunks are zstd-compressed, at most [`Options::chunk_size`] bytes before
//!   compression, and a chunk is closed and written at the latest [`Options::flush_interval`]
//!   (one second) after its first message: a process killed with SIGKILL loses at most its
//!   last second of log.
//! - Reading ([`read_summary`]): per-channel counts, time span and metadata from the file's
//!   summary; when the summary is missing (the writer was killed) the file is read from the
//!   start and every complete chunk is recovered. [`recover`] rewrites such a file as a valid
//!   MCAP file.
//!
//! Times are nanoseconds since the Unix epoch ([`now_ns`]), both as log time and publish time.

mod foxglove;
mod read;
mod write;

pub use foxglove::{
    Color, CompressedImage, CubePrimitive, Log, LogLevel, Pose, Quaternion, RawImage, SceneEntity,
    SceneUpdate, Vector3, timestamp,
};
pub use read::{
    ChannelSummary, FileSummary, json_messages, newest_json_message, proto_messages, read_summary,
    recover, timed_json_messages,
};
pub use write::{Options, RunLog, segments};

use std::path::PathBuf;

/// Topic of the `foxglove.Log` lines written by [`RunLog::log_line`].
pub const LOG_TOPIC: &str = "/log";

/// Name of the metadata record [`RunLog::create`] writes about the process (its `name`,
/// `pid` and `start_ns`).
pub const PROCESS_METADATA: &str = "process";

/// What went wrong, always naming the file.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing the file failed.
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The MCAP library refused a record.
    #[error("{}: {source}", .path.display())]
    Mcap {
        path: PathBuf,
        #[source]
        source: mcap::McapError,
    },
    /// The file has no bytes at all.
    #[error("{} is empty: not an MCAP file", .path.display())]
    Empty { path: PathBuf },
    /// The file does not begin with the MCAP magic bytes.
    #[error("{} is not an MCAP file (it does not begin with the MCAP magic bytes)", .path.display())]
    NotMcap { path: PathBuf },
    /// A message or schema that cannot go on this topic.
    #[error("{}: topic {topic}: {reason}", .path.display())]
    Topic {
        path: PathBuf,
        topic: String,
        reason: String,
    },
    /// An earlier write (possibly the background flush) failed; the log takes no more.
    #[error("{}: the log stopped after an earlier failure: {reason}", .path.display())]
    Failed { path: PathBuf, reason: String },
    /// [`recover`] was asked to write over its input.
    #[error("{}: recovering a file into itself would destroy it; name another output", .path.display())]
    SameFile { path: PathBuf },
}

/// Results of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// An [`Error::Io`] naming `path`.
pub(crate) fn io_err(path: &std::path::Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// An [`Error::Mcap`] naming `path`.
pub(crate) fn mcap_err(path: &std::path::Path, source: mcap::McapError) -> Error {
    Error::Mcap {
        path: path.to_path_buf(),
        source,
    }
}

/// Nanoseconds since the Unix epoch, now.
pub fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}
