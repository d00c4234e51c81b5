//! What a [`RunLog`](crate::RunLog) holds behind its mutex: the open file, its topics and
//! schemas, and the background thread that closes chunks in time.

use std::collections::{BTreeMap, HashMap};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mcap::records::Metadata;

use super::segment::{McapWriter, Options, open_writer, segment_path};
use crate::foxglove::{self, ProtoSchema};
use crate::{Error, Result, mcap_err};

/// What a topic carries; a topic keeps the kind of its first message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) enum Kind {
    Json,
    RawImage,
    CompressedImage,
    Log,
    SceneUpdate,
}

impl Kind {
    pub(super) fn describe(self) -> &'static str {
        match self {
            Kind::Json => "JSON messages",
            Kind::RawImage => "foxglove.RawImage",
            Kind::CompressedImage => "foxglove.CompressedImage",
            Kind::Log => "foxglove.Log",
            Kind::SceneUpdate => "foxglove.SceneUpdate",
        }
    }

    pub(super) fn proto_schema(self) -> Option<ProtoSchema> {
        match self {
            Kind::Json => None,
            Kind::RawImage => Some(foxglove::raw_image_schema()),
            Kind::CompressedImage => Some(foxglove::compressed_image_schema()),
            Kind::Log => Some(foxglove::log_schema()),
            Kind::SceneUpdate => Some(foxglove::scene_update_schema()),
        }
    }
}

pub(super) struct Topic {
    pub(super) channel: u16,
    pub(super) sequence: u32,
    pub(super) kind: Kind,
    /// Its declared JSON schema (name, schema), which every later segment declares again.
    pub(super) json_schema: Option<(String, String)>,
}

pub(super) struct State {
    /// `None` once finished.
    pub(super) writer: Option<McapWriter>,
    /// The file being written: the log's own path, then each later segment's.
    pub(super) path: PathBuf,
    pub(super) options: Options,
    /// The segment being written (0: the log's own path), and when it ends.
    pub(super) segment: u32,
    pub(super) segment_ends: Option<Instant>,
    /// Every metadata record written, which every later segment repeats.
    pub(super) metadata: Vec<Metadata>,
    /// Why the background flush failed; every later call reports it.
    pub(super) failure: Option<String>,
    pub(super) topics: HashMap<String, Topic>,
    pub(super) proto_schemas: HashMap<Kind, u16>,
    /// When the oldest message not yet in a closed chunk was logged.
    pub(super) oldest_unflushed: Option<Instant>,
}

pub(super) struct Shared {
    pub(super) path: PathBuf,
    /// False for a [`RunLog::disabled`](crate::RunLog::disabled) log, which takes every call
    /// and writes nothing.
    pub(super) enabled: bool,
    pub(super) flush_interval: Option<Duration>,
    pub(super) state: Mutex<State>,
}

impl Shared {
    pub(super) fn lock(&self) -> MutexGuard<'_, State> {
        // A panic elsewhere while holding the lock leaves the writer usable.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl State {
    pub(super) fn writer(&mut self) -> Result<&mut McapWriter> {
        if let Some(reason) = &self.failure {
            return Err(Error::Failed {
                path: self.path.clone(),
                reason: reason.clone(),
            });
        }
        self.writer.as_mut().ok_or_else(|| Error::Failed {
            path: self.path.clone(),
            reason: "the log is finished".into(),
        })
    }

    pub(super) fn add_channel(
        &mut self,
        topic: &str,
        kind: Kind,
        json_schema: Option<(String, String)>,
    ) -> Result<&mut Topic> {
        self.writer()?;
        let (path, writer) = (&self.path, self.writer.as_mut().expect("checked above"));
        let (schema_id, encoding) = match kind.proto_schema() {
            Some(proto) => {
                let id = match self.proto_schemas.get(&kind) {
                    Some(&id) => id,
                    None => {
                        let id = writer
                            .add_schema(proto.name, "protobuf", &proto.descriptor_set)
                            .map_err(|e| mcap_err(path, e))?;
                        self.proto_schemas.insert(kind, id);
                        id
                    }
                };
                (id, "protobuf")
            }
            None => {
                let default_schema;
                let (name, schema) = match &json_schema {
                    Some((name, schema)) => (name.as_str(), schema.as_str()),
                    None => {
                        default_schema =
                            serde_json::json!({"title": topic, "type": "object"}).to_string();
                        (topic.trim_start_matches('/'), default_schema.as_str())
                    }
                };
                let id = writer
                    .add_schema(name, "jsonschema", schema.as_bytes())
                    .map_err(|e| mcap_err(path, e))?;
                (id, "json")
            }
        };
        let channel = writer
            .add_channel(schema_id, topic, encoding, &BTreeMap::new())
            .map_err(|e| mcap_err(path, e))?;
        let entry = Topic {
            channel,
            sequence: 0,
            kind,
            json_schema,
        };
        self.topics.insert(topic.to_string(), entry);
        Ok(self.topics.get_mut(topic).expect("just inserted"))
    }

    pub(super) fn write_metadata(&mut self, record: &Metadata) -> Result<()> {
        self.writer()?
            .write_metadata(record)
            .map_err(|e| mcap_err(&self.path, e))
    }

    pub(super) fn flush(&mut self) -> Result<()> {
        self.writer()?
            .flush()
            .map_err(|e| mcap_err(&self.path, e))?;
        self.oldest_unflushed = None;
        Ok(())
    }

    /// Flushes when the oldest unwritten message will be `interval` old within `ahead`.
    pub(super) fn flush_if_due(
        &mut self,
        interval: Option<Duration>,
        ahead: Duration,
    ) -> Result<()> {
        match (interval, self.oldest_unflushed) {
            (Some(interval), Some(oldest)) if oldest.elapsed() + ahead >= interval => self.flush(),
            _ => Ok(()),
        }
    }

    /// Writes the last chunk and the summary (counts, indexes) of the file being written, and
    /// closes it.
    pub(super) fn finish_file(&mut self) -> Result<()> {
        self.writer()?;
        let Some(mut writer) = self.writer.take() else {
            return Ok(());
        };
        writer.finish().map_err(|e| mcap_err(&self.path, e))?;
        writer.into_inner().flush().map_err(|source| Error::Io {
            path: self.path.clone(),
            source,
        })
    }

    /// Ends the file being written and goes on in the next segment, which declares again
    /// every topic (its messages' sequence numbers going on) and every metadata record.
    pub(super) fn next_segment(&mut self, log: &Path) -> Result<()> {
        self.finish_file()?;
        self.oldest_unflushed = None;
        self.segment += 1;
        self.path = segment_path(log, self.segment);
        self.writer = Some(open_writer(&self.path, &self.options)?);
        self.segment_ends = self
            .options
            .segment_every
            .map(|every| Instant::now() + every);
        for record in std::mem::take(&mut self.metadata) {
            self.write_metadata(&record)?;
            self.metadata.push(record);
        }
        self.proto_schemas.clear();
        let mut topics: Vec<(String, Topic)> =
            std::mem::take(&mut self.topics).into_iter().collect();
        topics.sort_by_key(|(_, topic)| topic.channel);
        for (name, topic) in topics {
            self.add_channel(&name, topic.kind, topic.json_schema)?
                .sequence = topic.sequence;
        }
        Ok(())
    }
}

/// The background thread that closes chunks in time when the process logs nothing more. It
/// ends when the sender is dropped.
pub(super) fn spawn_flusher(
    shared: Arc<Shared>,
    interval: Duration,
) -> Result<(mpsc::Sender<()>, JoinHandle<()>)> {
    let (stop, stopped) = mpsc::channel::<()>();
    let tick = (interval / 10).max(Duration::from_millis(1));
    let path = shared.path.clone();
    let thread = std::thread::Builder::new()
        .name("mcaplog-flush".into())
        .spawn(move || {
            while let Err(RecvTimeoutError::Timeout) = stopped.recv_timeout(tick) {
                let mut state = shared.lock();
                if state.failure.is_some() || state.writer.is_none() {
                    return;
                }
                // Flush one tick early: the next check would come too late.
                if let Err(e) = state.flush_if_due(Some(interval), tick) {
                    state.failure = Some(e.to_string());
                    return;
                }
            }
        })
        .map_err(|source| Error::Io { path, source })?;
    Ok((stop, thread))
}
