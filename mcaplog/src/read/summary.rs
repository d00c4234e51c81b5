//! [`FileSummary`]: what a run log file holds, per channel, and how it is printed.

use std::collections::BTreeMap;
use std::fmt;
use std::path::PathBuf;

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
