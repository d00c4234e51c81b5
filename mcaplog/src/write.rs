//! [`RunLog`]: one process's MCAP file, written as it runs.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Metadata};
use prost::Message as _;
use serde::Serialize;

use crate::foxglove::{self, ProtoSchema};
use crate::{Error, LOG_TOPIC, LogLevel, PROCESS_METADATA, Result, now_ns};

/// How a [`RunLog`] cuts and writes its chunks.
#[derive(Clone, Debug)]
pub struct Options {
    /// A chunk is closed once it holds this many bytes before compression (default 1 MiB).
    pub chunk_size: u64,
    /// Every message is in the file (closed into a complete chunk and handed to the operating
    /// system) at most this long after it was logged (default 1 s). A background thread checks
    /// ten times per interval, so this holds when the process logs nothing more; `None` leaves
    /// it to the chunk size, [`RunLog::flush`] and the end.
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

type McapWriter = mcap::Writer<BufWriter<File>>;

/// What a topic carries; a topic keeps the kind of its first message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Kind {
    Json,
    RawImage,
    CompressedImage,
    Log,
    SceneUpdate,
}

impl Kind {
    fn describe(self) -> &'static str {
        match self {
            Kind::Json => "JSON messages",
            Kind::RawImage => "foxglove.RawImage",
            Kind::CompressedImage => "foxglove.CompressedImage",
            Kind::Log => "foxglove.Log",
            Kind::SceneUpdate => "foxglove.SceneUpdate",
        }
    }

    fn proto_schema(self) -> Option<ProtoSchema> {
        match self {
            Kind::Json => None,
            Kind::RawImage => Some(foxglove::raw_image_schema()),
            Kind::CompressedImage => Some(foxglove::compressed_image_schema()),
            Kind::Log => Some(foxglove::log_schema()),
            Kind::SceneUpdate => Some(foxglove::scene_update_schema()),
        }
    }
}

struct Topic {
    channel: u16,
    sequence: u32,
    kind: Kind,
    /// Its declared JSON schema (name, schema), which every later segment declares again.
    json_schema: Option<(String, String)>,
}

struct State {
    /// `None` once finished.
    writer: Option<McapWriter>,
    /// The file being written: the log's own path, then each later segment's.
    path: PathBuf,
    options: Options,
    /// The segment being written (0: the log's own path), and when it ends.
    segment: u32,
    segment_ends: Option<Instant>,
    /// Every metadata record written, which every later segment repeats.
    metadata: Vec<Metadata>,
    /// Why the background flush failed; every later call reports it.
    failure: Option<String>,
    topics: HashMap<String, Topic>,
    proto_schemas: HashMap<Kind, u16>,
    /// When the oldest message not yet in a closed chunk was logged.
    oldest_unflushed: Option<Instant>,
}

struct Shared {
    path: PathBuf,
    /// False for a [`RunLog::disabled`] log, which takes every call and writes nothing.
    enabled: bool,
    flush_interval: Option<Duration>,
    state: Mutex<State>,
}

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

    /// Logs `value` (which must serialize to a JSON object) on `topic`, timestamped now.
    pub fn json<T: Serialize + ?Sized>(&self, topic: &str, value: &T) -> Result<()> {
        self.json_at(topic, now_ns(), value)
    }

    /// Logs `value` (which must serialize to a JSON object) on `topic` at `time_ns`.
    pub fn json_at<T: Serialize + ?Sized>(
        &self,
        topic: &str,
        time_ns: u64,
        value: &T,
    ) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let path = &self.shared.path;
        let data = serde_json::to_vec(value)
            .map_err(|e| topic_err(path, topic, format!("cannot encode as JSON: {e}")))?;
        if data.first() != Some(&b'{') {
            return Err(topic_err(
                path,
                topic,
                "a JSON message must be an object".into(),
            ));
        }
        self.write(topic, Kind::Json, time_ns, &data)
    }

    /// Logs an uncompressed image as `foxglove.RawImage` at `timestamp_ns`. `encoding` is one
    /// of `rgb8`, `bgr8`, `rgba8`, `bgra8`, `mono8`, `mono16` (little-endian) or `32FC1`
    /// (little-endian f32, shown as brightness from 0 to 1); `data` holds the rows without
    /// padding.
    pub fn raw_image(
        &self,
        topic: &str,
        timestamp_ns: u64,
        width: u32,
        height: u32,
        encoding: &str,
        data: &[u8],
    ) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let path = &self.shared.path;
        let bytes_per_pixel = match encoding {
            "mono8" | "8UC1" => 1,
            "mono16" | "16UC1" => 2,
            "rgb8" | "bgr8" => 3,
            "rgba8" | "bgra8" | "32FC1" => 4,
            other => {
                return Err(topic_err(
                    path,
                    topic,
                    format!(
                        "unsupported image encoding {other:?} (rgb8, bgr8, rgba8, bgra8, mono8, mono16, 32FC1)"
                    ),
                ));
            }
        };
        let step = width as usize * bytes_per_pixel;
        if data.len() != step * height as usize {
            return Err(topic_err(
                path,
                topic,
                format!(
                    "a {width}x{height} {encoding} image has {} bytes, not {}",
                    step * height as usize,
                    data.len()
                ),
            ));
        }
        let message = foxglove::RawImage {
            timestamp: Some(foxglove::timestamp(timestamp_ns)),
            frame_id: String::new(),
            width,
            height,
            encoding: encoding.to_string(),
            step: step as u32,
            data: data.to_vec(),
        };
        self.write(
            topic,
            Kind::RawImage,
            timestamp_ns,
            &message.encode_to_vec(),
        )
    }

    /// Logs an encoded image (`format`: `png`, `jpeg`, `webp` or `avif`) as
    /// `foxglove.CompressedImage` at `timestamp_ns`.
    pub fn compressed_image(
        &self,
        topic: &str,
        timestamp_ns: u64,
        format: &str,
        data: &[u8],
    ) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let message = foxglove::CompressedImage {
            timestamp: Some(foxglove::timestamp(timestamp_ns)),
            frame_id: String::new(),
            data: data.to_vec(),
            format: format.to_string(),
        };
        self.write(
            topic,
            Kind::CompressedImage,
            timestamp_ns,
            &message.encode_to_vec(),
        )
    }

    /// Logs a 3D scene as `foxglove.SceneUpdate` at `timestamp_ns`.
    pub fn scene_update(
        &self,
        topic: &str,
        timestamp_ns: u64,
        update: &foxglove::SceneUpdate,
    ) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        self.write(
            topic,
            Kind::SceneUpdate,
            timestamp_ns,
            &update.encode_to_vec(),
        )
    }

    /// Logs a line as `foxglove.Log` on [`LOG_TOPIC`], named with the process, timestamped now.
    pub fn log_line(&self, level: LogLevel, message: &str) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let time_ns = now_ns();
        let line = foxglove::Log {
            timestamp: Some(foxglove::timestamp(time_ns)),
            level: level as i32,
            message: message.to_string(),
            name: self.process.clone(),
            file: String::new(),
            line: 0,
        };
        self.write(LOG_TOPIC, Kind::Log, time_ns, &line.encode_to_vec())
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

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic elsewhere while holding the lock leaves the writer usable.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl State {
    fn writer(&mut self) -> Result<&mut McapWriter> {
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

    fn add_channel(
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

    fn write_metadata(&mut self, record: &Metadata) -> Result<()> {
        self.writer()?
            .write_metadata(record)
            .map_err(|e| mcap_err(&self.path, e))
    }

    fn flush(&mut self) -> Result<()> {
        self.writer()?
            .flush()
            .map_err(|e| mcap_err(&self.path, e))?;
        self.oldest_unflushed = None;
        Ok(())
    }

    /// Flushes when the oldest unwritten message will be `interval` old within `ahead`.
    fn flush_if_due(&mut self, interval: Option<Duration>, ahead: Duration) -> Result<()> {
        match (interval, self.oldest_unflushed) {
            (Some(interval), Some(oldest)) if oldest.elapsed() + ahead >= interval => self.flush(),
            _ => Ok(()),
        }
    }

    /// Writes the last chunk and the summary (counts, indexes) of the file being written, and
    /// closes it.
    fn finish_file(&mut self) -> Result<()> {
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
    fn next_segment(&mut self, log: &Path) -> Result<()> {
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

/// A new MCAP file at `path` written the log's way.
fn open_writer(path: &Path, options: &Options) -> Result<McapWriter> {
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
fn segment_path(log: &Path, number: u32) -> PathBuf {
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

/// The background thread that closes chunks in time when the process logs nothing more. It
/// ends when the sender is dropped.
fn spawn_flusher(
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

fn mcap_err(path: &Path, source: mcap::McapError) -> Error {
    Error::Mcap {
        path: path.to_path_buf(),
        source,
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
