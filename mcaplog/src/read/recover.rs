//! [`recover`]: a file whose writer was killed, rewritten as a sound MCAP file.

use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::Path;

use mcap::records::Record;

use super::scan::{Tally, from_summary_section, open_mcap, scan, summary_problem};
use super::summary::FileSummary;
use crate::{Error, Result, io_err, mcap_err};

/// Rewrites the MCAP file `input` as a sound MCAP file `output` (schemas, channels, messages
/// with their ids, sequences and times, metadata, attachments; chunks, indexes and the summary
/// made anew), keeping everything [`read_summary`](crate::read_summary) would recover from it.
/// Returns the summary of what was recovered, read from `input`.
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
