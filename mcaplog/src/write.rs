//! [`RunLog`]: one process's MCAP file, written as it runs.

mod messages;
mod segment;
mod state;

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Metadata};

use crate::{Error, PROCESS_METADATA, Result, mcap_err, now_ns};
pub use segment::{Options, segments};
use segment::{open_writer, segment_path};
use state::{Kind, Shared, State, spawn_flusher};

/// One process's run log: an MCAP file that stays readable if the process dies.
///
/// All methods take `&self` (a mutex inside), so threads of one process can share a log.
/// Call [`RunLog::finish`] at the end to write the summary; dropping the log finishes it too,
/// without reporting errors.
pub struct RunLog {
    shared: Arc<Shared>,
    process: String,
    flusher: Option<(mpsc::Sender<()>, JoinHandle<()>)>,
}

impl RunLog {
    /// Creates (or truncates) the file at `path`, and its directory, with the default
    /// [`Options`], and records the process (`name`, `pid`, `start_ns`) as metadata.
    pub fn create(path: impl AsRef<Path>, process: &str) -> Result<RunLog> {
        Self::create_with(path, process, Options::default())
    }

    /// [`RunLog::create`] with other [`Options`]. Segments a log of this name left behind
    /// are removed: they are not this log's.
    pub fn create_with(path: impl AsRef<Path>, process: &str, options: Options) -> Result<RunLog> {
        let path = path.as_ref();
        for stale in segments(path).into_iter().skip(1) {
            std::fs::remove_file(&stale).map_err(|source| Error::Io {
                path: stale.clone(),
                source,
            })?;
        }
        Self::open(path, 0, process, options)
    }

    /// Goes on after the log already at `path`, as a resumed run does: its files are kept, and
    /// this process writes the log's next segment (from `<stem>.<n>.mcap`, the first number
    /// free), so that [`segments`] reads the earlier process's messages and then this one's.
    /// With no log at `path`, the same as [`RunLog::create_with`].
    pub fn continue_with(
        path: impl AsRef<Path>,
        process: &str,
        options: Options,
    ) -> Result<RunLog> {
        let path = path.as_ref();
        let next = segments(path).len() as u32;
        Self::open(path, next, process, options)
    }

    /// A log whose first file written is segment `segment` of the log at `path`.
    fn open(path: &Path, segment: u32, process: &str, options: Options) -> Result<RunLog> {
        let path = path.to_path_buf();
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| Error::Io {
                path: path.clone(),
                source,
            })?;
        }
        let first = segment_path(&path, segment);
        let shared = Arc::new(Shared {
            path: path.clone(),
            enabled: true,
            flush_interval: options.flush_interval,
            state: Mutex::new(State {
                writer: Some(open_writer(&first, &options)?),
                segment,
                segment_ends: options.segment_every.map(|every| Instant::now() + every),
                path: first,
                options: options.clone(),
                metadata: Vec::new(),
                failure: None,
                topics: HashMap::new(),
                proto_schemas: HashMap::new(),
                oldest_unflushed: None,
            }),
        });
        let flusher = options
            .flush_interval
            .map(|interval| spawn_flusher(Arc::clone(&shared), interval))
            .transpose()?;
        let log = RunLog {
            shared,
            process: process.to_string(),
            flusher,
        };
        let process_record = BTreeMap::from([
            ("name".to_string(), process.to_string()),
            ("pid".to_string(), std::process::id().to_string()),
            ("start_ns".to_string(), now_ns().to_string()),
        ]);
        log.metadata(PROCESS_METADATA, &process_record)?;
        Ok(log)
    }

    /// A log that takes every call and writes nothing (no file, no encoding): for runs with
    /// logging switched off, and for measuring what logging costs.
    pub fn disabled(process: &str) -> RunLog {
        RunLog {
            shared: Arc::new(Shared {
                path: PathBuf::new(),
                enabled: false,
                flush_interval: None,
                state: Mutex::new(State {
                    writer: None,
                    path: PathBuf::new(),
                    options: Options::default(),
                    segment: 0,
                    segment_ends: None,
                    metadata: Vec::new(),
                    failure: None,
                    topics: HashMap::new(),
                    proto_schemas: HashMap::new(),
                    oldest_unflushed: None,
                }),
            }),
            process: process.to_string(),
            flusher: None,
        }
    }

    /// Whether this log writes a file (false for [`RunLog::disabled`]).
    pub fn enabled(&self) -> bool {
        self.shared.enabled
    }

    /// The log's path: its first file, with any later segments beside it (empty for a
    /// disabled log).
    pub fn path(&self) -> &Path {
        &self.shared.path
    }

    /// The process name given at creation.
    pub fn process(&self) -> &str {
        &self.process
    }

    /// Writes a metadata record (e.g. `"config"` with the resolved configuration, flattened to
    /// dotted keys) and flushes, so it survives a crash right after.
    pub fn metadata(&self, name: &str, values: &BTreeMap<String, String>) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let mut state = self.shared.lock();
        let record = Metadata {
            name: name.to_string(),
            metadata: values.clone(),
        };
        state.write_metadata(&record)?;
        state.metadata.push(record);
        state.flush()
    }

    /// Declares a JSON topic with its own JSON schema (`schema`, a JSON Schema document, under
    /// `schema_name`), before its first message. Topics never declared get a permissive schema
    /// `{"type": "object"}` titled with the topic; generic readers decode either.
    pub fn json_schema(&self, topic: &str, schema_name: &str, schema: &str) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let path = &self.shared.path;
        if let Err(e) = serde_json::from_str::<serde_json::Value>(schema) {
            return Err(topic_err(
                path,
                topic,
                format!("the schema is not JSON: {e}"),
            ));
        }
        let mut state = self.shared.lock();
        if state.topics.contains_key(topic) {
            return Err(topic_err(
                path,
                topic,
                "already has a channel: declare its schema before its first message".into(),
            ));
        }
        let declared = (schema_name.to_string(), schema.to_string());
        state.add_channel(topic, Kind::Json, Some(declared))?;
        Ok(())
    }

    /// Closes the open chunk and hands everything to the operating system now.
    pub fn flush(&self) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        self.shared.lock().flush()
    }

    /// Flushes if the oldest unwritten message is older than the flush interval. Every write
    /// does this, and so does the background thread; a caller never needs to.
    pub fn flush_if_due(&self) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let interval = self.shared.flush_interval;
        self.shared.lock().flush_if_due(interval, Duration::ZERO)
    }

    /// Writes the last chunk and the summary (counts, indexes), and closes the file.
    pub fn finish(mut self) -> Result<()> {
        self.close()
    }

    fn close(&mut self) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        if let Some((stop, thread)) = self.flusher.take() {
            drop(stop);
            let _ = thread.join();
        }
        self.shared.lock().finish_file()
    }

    fn write(&self, topic: &str, kind: Kind, time_ns: u64, data: &[u8]) -> Result<()> {
        let mut state = self.shared.lock();
        let state = &mut *state;
        state.writer()?;
        if state
            .segment_ends
            .is_some_and(|ends| Instant::now() >= ends)
        {
            state.next_segment(&self.shared.path)?;
        }
        let topic_entry = match state.topics.get_mut(topic) {
            Some(t) => t,
            None => state.add_channel(topic, kind, None)?,
        };
        let (carries, channel_id, sequence) =
            (topic_entry.kind, topic_entry.channel, topic_entry.sequence);
        if carries != kind {
            return Err(topic_err(
                &state.path,
                topic,
                format!("carries {}, not {}", carries.describe(), kind.describe()),
            ));
        }
        topic_entry.sequence = sequence.wrapping_add(1);
        let header = MessageHeader {
            channel_id,
            sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        state
            .writer
            .as_mut()
            .expect("checked above")
            .write_to_known_channel(&header, data)
            .map_err(|e| mcap_err(&state.path, e))?;
        state.oldest_unflushed.get_or_insert_with(Instant::now);
        state.flush_if_due(self.shared.flush_interval, Duration::ZERO)
    }
}

impl Drop for RunLog {
    fn drop(&mut self) {
        let _ = self.close();
    }
}

fn topic_err(path: &Path, topic: &str, reason: String) -> Error {
    Error::Topic {
        path: path.to_path_buf(),
        topic: topic.to_string(),
        reason,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_can_be_shared_between_threads() {
        fn shareable<T: Send + Sync>() {}
        shareable::<RunLog>();
    }
}
