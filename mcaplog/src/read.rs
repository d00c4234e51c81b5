//! Reading run logs back: summaries, and recovery of files whose writer was killed.

mod recover;
mod scan;
mod summary;

use std::collections::HashMap;
use std::io::{Seek, SeekFrom};
use std::path::Path;

use mcap::records::Record;

use crate::{Error, Result, io_err, segments};
pub use recover::recover;
use scan::{Tally, from_summary_section, open_mcap, scan, summary_problem};
pub use summary::{ChannelSummary, FileSummary};

/// Summarises the MCAP file at `path`: per-channel message counts, time span and metadata.
///
/// A sound file is summarised from its summary section without reading its messages. A file
/// without one (its writer was killed) is read from the start; every complete chunk counts,
/// and the result says `recovered`. A file that is empty or is not MCAP is an error naming it.
pub fn read_summary(path: impl AsRef<Path>) -> Result<FileSummary> {
    let path = path.as_ref();
    let (mut file, bytes) = open_mcap(path)?;
    let summary_problem = match from_summary_section(&mut file, path, bytes) {
        Ok(Some(summary)) => return Ok(summary),
        Ok(None) => None,
        Err(e) => Some(summary_problem(e)),
    };
    file.seek(SeekFrom::Start(0)).map_err(|e| io_err(path, e))?;
    let mut tally = Tally::default();
    let end = scan(&mut file, path, |record| {
        tally.add(&record);
        Ok(())
    })?;
    Ok(tally.finish(path, bytes, summary_problem, end))
}

/// The JSON messages on `topic`, in file order, read from the start (so a file cut by a
/// crash gives every message of its complete chunks). A message that is not JSON is an error
/// naming the file and the topic.
pub fn json_messages(path: impl AsRef<Path>, topic: &str) -> Result<Vec<serde_json::Value>> {
    let messages = timed_json_messages(path, topic)?;
    Ok(messages.into_iter().map(|(_, value)| value).collect())
}

/// [`json_messages`], each with its log time (ns since the Unix epoch).
pub fn timed_json_messages(
    path: impl AsRef<Path>,
    topic: &str,
) -> Result<Vec<(u64, serde_json::Value)>> {
    topic_messages(path.as_ref(), topic, "json", |data| {
        serde_json::from_slice(data).map_err(|e| format!("a message is not JSON: {e}"))
    })
}

/// The newest JSON message on `topic` of the log at `log`, its segments ([`segments`]) read
/// newest first; `None` when no file of it has one. A file still being written is read as
/// far as its complete chunks go.
pub fn newest_json_message(
    log: impl AsRef<Path>,
    topic: &str,
) -> Result<Option<serde_json::Value>> {
    for file in segments(log.as_ref()).iter().rev() {
        if let Some(newest) = json_messages(file, topic)?.pop() {
            return Ok(Some(newest));
        }
    }
    Ok(None)
}

/// Every protobuf message on `topic` (e.g. a `foxglove.RawImage`), decoded as `M`, with its
/// log time, in file order; empty when the file has no such topic.
pub fn proto_messages<M: prost::Message + Default>(
    path: impl AsRef<Path>,
    topic: &str,
) -> Result<Vec<(u64, M)>> {
    topic_messages(path.as_ref(), topic, "protobuf", |data| {
        M::decode(data).map_err(|e| format!("a message does not decode: {e}"))
    })
}

/// The messages on `topic` in `encoding`, decoded, with their log times.
fn topic_messages<T>(
    path: &Path,
    topic: &str,
    encoding: &str,
    decode: impl Fn(&[u8]) -> Result<T, String>,
) -> Result<Vec<(u64, T)>> {
    let (mut file, _) = open_mcap(path)?;
    let mut channels: HashMap<u16, bool> = HashMap::new();
    let mut values = Vec::new();
    scan(&mut file, path, |record| {
        match record {
            Record::Channel(c) => {
                channels.insert(c.id, c.topic == topic && c.message_encoding == encoding);
            }
            Record::Message { header, data } if channels.get(&header.channel_id) == Some(&true) => {
                let value = decode(&data).map_err(|reason| Error::Topic {
                    path: path.to_path_buf(),
                    topic: topic.to_string(),
                    reason,
                })?;
                values.push((header.log_time, value));
            }
            _ => {}
        }
        Ok(())
    })?;
    Ok(values)
}
