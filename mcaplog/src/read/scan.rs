//! Reading a file's records: its summary section when it has a sound one, else every record
//! from the start, counted as it comes.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{self, Read, Seek, SeekFrom};
use std::path::Path;

use mcap::records::{self, Record};
use mcap::sans_io::{
    LinearReadEvent, LinearReader, LinearReaderOptions, SummaryReadEvent, SummaryReader,
    SummaryReaderOptions,
};

use super::summary::{ChannelSummary, FileSummary};
use crate::{Error, Result, io_err};

/// Opens `path`, checks that it begins like an MCAP file, and gives its size.
pub(super) fn open_mcap(path: &Path) -> Result<(File, u64)> {
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
pub(super) fn summary_problem(e: mcap::McapError) -> String {
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
pub(super) fn from_summary_section(
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
pub(super) struct ScanEnd {
    /// The footer was reached.
    footer: bool,
    /// The error that stopped the read, if one did.
    stopped: Option<String>,
}

/// Reads the file from the start, handing every record (chunks opened, and only once their
/// CRC holds: a cut chunk yields nothing) to `visit`, until the footer, the end of the file,
/// or the first record that cannot be read.
pub(super) fn scan(
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
pub(super) struct Tally {
    schemas: HashMap<u16, String>,
    channels: BTreeMap<u16, ChannelSummary>,
    messages: u64,
    undeclared: u64,
    span: Option<(u64, u64)>,
    metadata: Vec<(String, BTreeMap<String, String>)>,
}

impl Tally {
    pub(super) fn add(&mut self, record: &Record<'_>) {
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

    pub(super) fn finish(
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
