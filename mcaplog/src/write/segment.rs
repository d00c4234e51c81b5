//! A log's files: the [`Options`] they are written with, and the segments a log goes on in.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::{Error, Result, mcap_err};

/// How a [`RunLog`](crate::RunLog) cuts and writes its chunks.
#[derive(Clone, Debug)]
pub struct Options {
    /// A chunk is closed once it holds this many bytes before compression (default 1 MiB).
    pub chunk_size: u64,
    /// Every message is in the file (closed into a complete chunk and handed to the operating
    /// system) at most this long after it was logged (default 1 s). A background thread checks
    /// ten times per interval, so this holds when the process logs nothing more; `None` leaves
    /// it to the chunk size, [`RunLog::flush`](crate::RunLog::flush) and the end.
    pub flush_interval: Option<Duration>,
    /// zstd level of the chunks; 0 is zstd's default (3).
    pub zstd_level: u32,
    /// After this long the log goes on in a new file, its next segment (`<stem>.1.mcap`,
    /// `<stem>.2.mcap`, ...: [`segments`]), each file complete in itself (default an
    /// hour; `None`: one file). The writer holds every chunk's index until its file ends, a
    /// few hundred bytes a chunk, a chunk a second: without segments a process logging for
    /// days would hold tens of MB of them.
    pub segment_every: Option<Duration>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            chunk_size: 1 << 20,
            flush_interval: Some(Duration::from_secs(1)),
            zstd_level: 0,
            segment_every: Some(Duration::from_secs(3600)),
        }
    }
}

pub(super) type McapWriter = mcap::Writer<BufWriter<File>>;

/// A new MCAP file at `path` written the log's way.
pub(super) fn open_writer(path: &Path, options: &Options) -> Result<McapWriter> {
    let file = File::create(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_level(options.zstd_level)
        // One thread per process: the roles need the cores more than the log does.
        .compression_threads(0)
        .chunk_size(Some(options.chunk_size))
        // Keep the open chunk in memory and write it whole when it closes: the file then
        // only ever ends in a partial record while that one write is under way.
        .disable_seeking(true)
        .library(format!(
            "pushgrasp-mcaplog/{} {}",
            env!("CARGO_PKG_VERSION"),
            mcap::LIBRARY_IDENTIFIER
        ))
        .create(BufWriter::new(file))
        .map_err(|e| mcap_err(path, e))
}

/// The file of a log's segment `number`: the log's own path for 0, else `<stem>.<number>.mcap`
/// beside it.
pub(super) fn segment_path(log: &Path, number: u32) -> PathBuf {
    if number == 0 {
        return log.to_path_buf();
    }
    let stem = log.file_stem().unwrap_or_default().to_string_lossy();
    log.with_file_name(format!("{stem}.{number}.mcap"))
}

/// The files of the log at `log` that exist, in order: the log's own, then its segments.
pub fn segments(log: &Path) -> Vec<PathBuf> {
    (0..)
        .map(|number| segment_path(log, number))
        .take_while(|path| path.exists())
        .collect()
}
