//! Reading run logs back: summaries, and recovery of files whose writer was killed.

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::fs::File;
use std::io::{self, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use mcap::records::{self, Record};
use mcap::sans_io::{
    LinearReadEvent, LinearReader, LinearReaderOptions, SummaryReadEvent, SummaryReader,
    SummaryReaderOptions,
};

use crate::{Error, Result, segments};

/// One channel of a file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelSummary {
    /// Channel id in the file.
    pub id: u16,
    /// Its topic.
    pub topic: String,
    /// Name of its schema (`foxglove.RawImage`, ...), empty when it has none.
    pub schema_name: String,
    /// Encoding of its messages (`json`, `protobuf`).
    pub message_encoding: String,
    /// How many messages it holds.
    pub messages: u64,
}

/// What a file holds, from its summary or, when that is missing, from reading it through.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FileSummary {
    /// The file.
    pub path: PathBuf,
    /// Its size in bytes.
    pub bytes: u64,
    /// Its channels, by topic.
    pub channels: Vec<ChannelSummary>,
    /// Messages in all channels.
    pub messages: u64,
    /// Log times of the first and the last message (ns since the Unix epoch); `None` without
    /// messages.
    pub time_span_ns: Option<(u64, u64)>,
    /// Metadata records, name and values, in file order.
    pub metadata: Vec<(String, BTreeMap<String, String>)>,
    /// True when the file has no usable summary (its writer did not finish: killed, or the
    /// disk filled) and was read from the start instead: everything up to the first damaged
    /// or cut record, which is every complete chunk of a file cut short.
    pub recovered: bool,
    /// What was wrong with the file, in words; empty for a sound file.
    pub damage: Vec<String>,
}

impl FileSummary {
    /// Messages on `topic` (0 for a topic the file lacks).
    pub fn messages_on(&self, topic: &str) -> u64 {
        self.channels
            .iter()
            .filter(|c| c.topic == topic)
            .map(|c| c.messages)
            .sum()
    }

    /// The values of the first metadata record called `name`.
    pub fn metadata(&self, name: &str) -> Option<&BTreeMap<String, String>> {
        self.metadata
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, m)| m)
    }
}

impl fmt::Display for FileSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {} bytes, {} messages",
            self.path.display(),
            self.bytes,
            self.messages
        )?;
        if let Some((start, end)) = self.time_span_ns {
            write!(f, " over {:.3} s", (end - start) as f64 * 1e-9)?;
        }
        writeln!(f)?;
        if self.recovered {
            writeln!(
                f,
                "  damaged; recovered {} messages in the complete chunks",
                self.messages
            )?;
        }
        for damage in &self.damage {
            writeln!(f, "  - {damage}")?;
        }
        for c in &self.channels {
            writeln!(
                f,
                "  {:<28} {:>9} messages  {} ({})",
                c.topic, c.messages, c.schema_name, c.message_encoding
            )?;
        }
        for (name, values) in &self.metadata {
            write!(f, "  metadata {name}:")?;
            if values.len() <= 4 {
                for (k, v) in values {
                    write!(f, " {k}={v}")?;
                }
                writeln!(f)?;
            } else {
                writeln!(f, " {} entries", values.len())?;
            }
        }
        Ok(())
    }
}

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

/// Rewrites the MCAP file `input` as a sound MCAP file `output` (schemas, channels, messages
/// with their ids, sequences and times, metadata, attachments; chunks, indexes and the summary
/// made anew), keeping everything [`read_summary`] would recover from it. Returns the summary of
/// what was recovered, read from `input`.
pub fn recover(input: impl AsRef<Path>, output: impl AsRef<Path>) -> Result<FileSummary> {
    let (input, output) = (input.as_ref(), output.as_ref());
    let (mut file, bytes) = open_mcap(input)?;
    if let (Ok(a), Ok(b)) = (input.canonicalize(), output.canonicalize())
        && a == b
    {
        return Err(Error::SameFile {
            path: input.to_path_buf(),
        });
    }
    let summary_problem = from_summary_section(&mut file, input, bytes)
        .err()
        .map(summary_problem);
    file.seek(SeekFrom::Start(0))
        .map_err(|e| io_err(input, e))?;
    let out = File::create(output).map_err(|e| io_err(output, e))?;
    let mut writer: Option<OutWriter> = None;
    let new_writer = |profile: &str| {
        mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_threads(0)
            .profile(profile)
            .create(BufWriter::new(out.try_clone()?))
    };
    let mut tally = Tally::default();
    let mut skipped = 0u64;
    let end = scan(&mut file, input, |record| {
        tally.add(&record);
        copy_record(&mut writer, record, &new_writer, &mut skipped).map_err(|e| mcap_err(output, e))
    })?;
    let mut writer = match writer {
        Some(w) => w,
        None => new_writer("").map_err(|e| mcap_err(output, e))?,
    };
    writer.finish().map_err(|e| mcap_err(output, e))?;
    writer.into_inner().flush().map_err(|e| io_err(output, e))?;
    let mut summary = tally.finish(input, bytes, summary_problem, end);
    if skipped > 0 {
        summary.damage.push(format!(
            "{skipped} messages of undeclared channels left out"
        ));
    }
    Ok(summary)
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

type OutWriter = mcap::Writer<BufWriter<File>>;

/// Copies one record of the input into the recovered file (opening it at the first record).
fn copy_record(
    writer: &mut Option<OutWriter>,
    record: Record<'_>,
    new_writer: &impl Fn(&str) -> mcap::McapResult<OutWriter>,
    skipped: &mut u64,
) -> mcap::McapResult<()> {
    let w = match (&mut *writer, &record) {
        (Some(w), _) => w,
        (None, Record::Header(h)) => writer.insert(new_writer(&h.profile)?),
        (None, _) => writer.insert(new_writer("")?),
    };
    match record {
        Record::Schema { header, data } => {
            w.add_schema_with_id(header.id, &header.name, &header.encoding, &data)?;
        }
        Record::Channel(c) => {
            w.add_channel_with_id(
                c.id,
                c.schema_id,
                &c.topic,
                &c.message_encoding,
                &c.metadata,
            )?;
        }
        Record::Message { header, data } => match w.write_to_known_channel(&header, &data) {
            Ok(()) => {}
            // A message of a channel never declared cannot be kept.
            Err(mcap::McapError::UnknownChannel(..)) => *skipped += 1,
            Err(e) => return Err(e),
        },
        Record::Metadata(m) => w.write_metadata(&m)?,
        Record::Attachment { header, data, .. } => w.attach(&mcap::Attachment {
            log_time: header.log_time,
            create_time: header.create_time,
            name: header.name,
            media_type: header.media_type,
            data,
        })?,
        _ => {}
    }
    Ok(())
}

/// Opens `path`, checks that it begins like an MCAP file, and gives its size.
fn open_mcap(path: &Path) -> Result<(File, u64)> {
    let mut file = File::open(path).map_err(|e| io_err(path, e))?;
    let bytes = file.metadata().map_err(|e| io_err(path, e))?.len();
    if bytes == 0 {
        return Err(Error::Empty {
            path: path.to_path_buf(),
        });
    }
    let mut magic = [0u8; 8];
    let got = read_full(&mut file, &mut magic).map_err(|e| io_err(path, e))?;
    if got < magic.len() || magic != mcap::MAGIC {
        return Err(Error::NotMcap {
            path: path.to_path_buf(),
        });
    }
    file.seek(SeekFrom::Start(0)).map_err(|e| io_err(path, e))?;
    Ok((file, bytes))
}

fn read_full(file: &mut File, buf: &mut [u8]) -> io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match file.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

/// Says why the summary section could not be used.
fn summary_problem(e: mcap::McapError) -> String {
    match e {
        mcap::McapError::BadMagic | mcap::McapError::UnexpectedEof => {
            "no summary: the file does not end in a footer and the MCAP magic bytes (cut short)"
                .into()
        }
        e => format!("the summary section is unreadable ({e})"),
    }
}

/// The summary from the file's summary section; `None` when it has no statistics (then the
/// file must be read through to count).
fn from_summary_section(
    file: &mut File,
    path: &Path,
    bytes: u64,
) -> Result<Option<FileSummary>, mcap::McapError> {
    let mut reader =
        SummaryReader::new_with_options(SummaryReaderOptions::default().with_file_size(bytes));
    while let Some(event) = reader.next_event() {
        match event? {
            SummaryReadEvent::ReadRequest(n) => {
                let got = read_full(file, reader.insert(n))?;
                reader.notify_read(got);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let at = file.seek(to)?;
                reader.notify_seeked(at);
            }
        }
    }
    let Some(summary) = reader.finish() else {
        return Ok(None);
    };
    let Some(stats) = &summary.stats else {
        return Ok(None);
    };
    let mut channels: Vec<ChannelSummary> = summary
        .channels
        .values()
        .map(|c| ChannelSummary {
            id: c.id,
            topic: c.topic.clone(),
            schema_name: c
                .schema
                .as_ref()
                .map(|s| s.name.clone())
                .unwrap_or_default(),
            message_encoding: c.message_encoding.clone(),
            messages: stats
                .channel_message_counts
                .get(&c.id)
                .copied()
                .unwrap_or(0),
        })
        .collect();
    channels.sort_by(|a, b| (&a.topic, a.id).cmp(&(&b.topic, b.id)));
    let mut metadata = Vec::new();
    let mut indexes = summary.metadata_indexes.clone();
    indexes.sort_by_key(|i| i.offset);
    for index in &indexes {
        let mut buf = vec![0u8; index.length as usize];
        file.seek(SeekFrom::Start(index.offset))?;
        if read_full(file, &mut buf)? != buf.len() || buf.len() < 9 {
            return Err(mcap::McapError::BadIndex);
        }
        match mcap::parse_record(buf[0], &buf[9..])? {
            Record::Metadata(m) => metadata.push((m.name, m.metadata)),
            _ => return Err(mcap::McapError::BadIndex),
        }
    }
    Ok(Some(FileSummary {
        path: path.to_path_buf(),
        bytes,
        channels,
        messages: stats.message_count,
        time_span_ns: (stats.message_count > 0)
            .then_some((stats.message_start_time, stats.message_end_time)),
        metadata,
        recovered: false,
        damage: Vec::new(),
    }))
}

/// How a read from the start ended.
struct ScanEnd {
    /// The footer was reached.
    footer: bool,
    /// The error that stopped the read, if one did.
    stopped: Option<String>,
}

/// Reads the file from the start, handing every record (chunks opened, and only once their
/// CRC holds: a cut chunk yields nothing) to `visit`, until the footer, the end of the file,
/// or the first record that cannot be read.
fn scan(
    file: &mut File,
    path: &Path,
    mut visit: impl FnMut(Record<'_>) -> Result<()>,
) -> Result<ScanEnd> {
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_prevalidate_chunk_crcs(true),
    );
    let mut footer = false;
    while let Some(event) = reader.next_event() {
        let record = match event {
            Ok(LinearReadEvent::ReadRequest(n)) => {
                let got = read_full(file, reader.insert(n)).map_err(|e| io_err(path, e))?;
                reader.notify_read(got);
                continue;
            }
            Ok(LinearReadEvent::Record { opcode, data }) => mcap::parse_record(opcode, data),
            Err(e) => Err(e),
        };
        let record = match record {
            Ok(r) => r,
            Err(e) => {
                return Ok(ScanEnd {
                    footer,
                    stopped: Some(e.to_string()),
                });
            }
        };
        footer |= matches!(record, Record::Footer(_));
        visit(record)?;
    }
    Ok(ScanEnd {
        footer,
        stopped: None,
    })
}

/// Counts what a read from the start meets.
#[derive(Default)]
struct Tally {
    schemas: HashMap<u16, String>,
    channels: BTreeMap<u16, ChannelSummary>,
    messages: u64,
    undeclared: u64,
    span: Option<(u64, u64)>,
    metadata: Vec<(String, BTreeMap<String, String>)>,
}

impl Tally {
    fn add(&mut self, record: &Record<'_>) {
        match record {
            Record::Schema { header, .. } => {
                self.schemas.insert(header.id, header.name.clone());
            }
            Record::Channel(c) => {
                let schema_name = self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                // The summary section repeats channels: keep the counts.
                self.channels.entry(c.id).or_insert(ChannelSummary {
                    id: c.id,
                    topic: c.topic.clone(),
                    schema_name,
                    message_encoding: c.message_encoding.clone(),
                    messages: 0,
                });
            }
            Record::Message { header, .. } => match self.channels.get_mut(&header.channel_id) {
                Some(c) => {
                    c.messages += 1;
                    self.messages += 1;
                    let t = header.log_time;
                    self.span = Some(match self.span {
                        None => (t, t),
                        Some((a, b)) => (a.min(t), b.max(t)),
                    });
                }
                None => self.undeclared += 1,
            },
            Record::Metadata(records::Metadata { name, metadata }) => {
                self.metadata.push((name.clone(), metadata.clone()));
            }
            _ => {}
        }
    }

    fn finish(
        self,
        path: &Path,
        bytes: u64,
        summary_problem: Option<String>,
        end: ScanEnd,
    ) -> FileSummary {
        let mut damage = Vec::new();
        damage.extend(summary_problem);
        let cut = end.stopped.is_some() || !end.footer;
        match end.stopped {
            Some(e) => damage.push(format!("read from the start until: {e}")),
            None if !end.footer => damage.push("the file ends without a footer".into()),
            None => {}
        }
        if self.undeclared > 0 {
            damage.push(format!(
                "{} messages of undeclared channels not counted",
                self.undeclared
            ));
        }
        let recovered = !damage.is_empty() || cut;
        let mut channels: Vec<ChannelSummary> = self.channels.into_values().collect();
        channels.sort_by(|a, b| (&a.topic, a.id).cmp(&(&b.topic, b.id)));
        FileSummary {
            path: path.to_path_buf(),
            bytes,
            channels,
            messages: self.messages,
            time_span_ns: self.span,
            metadata: self.metadata,
            recovered,
            damage,
        }
    }
}

fn io_err(path: &Path, source: io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn mcap_err(path: &Path, source: mcap::McapError) -> Error {
    Error::Mcap {
        path: path.to_path_buf(),
        source,
    }
}
