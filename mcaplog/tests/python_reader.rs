//! The independent Python `mcap` reader (with `mcap-protobuf-support`) decodes our files, with
//! the counts our reader gives. Skipped, with a note, where Python lacks those packages; set
//! them up with
//! `python3 -m venv target/mcap-venv && target/mcap-venv/bin/pip install mcap mcap-protobuf-support`
//! or name an interpreter that has them in `MCAPLOG_PYTHON`.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use common::*;

/// Reads the file named by its argument, decodes every message by its encoding and schema,
/// checks what it can, and prints the counts, decoded messages and metadata as JSON.
const SCRIPT: &str = r#"
import json, sys
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

factory = DecoderFactory()
decoders = {}
counts = {}
decoded = 0
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f, validate_crcs=True)
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
        if channel.message_encoding == "protobuf":
            if channel.id not in decoders:
                decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
            m = decoders[channel.id](message.data)
            if schema.name in ("foxglove.RawImage", "foxglove.CompressedImage", "foxglove.Log"):
                stamp = m.timestamp.seconds * 1000000000 + m.timestamp.nanos
                assert stamp == message.log_time, (schema.name, stamp, message.log_time)
            if schema.name == "foxglove.RawImage":
                assert m.width > 0 and len(m.data) == m.step * m.height, m
            elif schema.name == "foxglove.CompressedImage":
                assert m.format == "png" and len(m.data) > 0
            elif schema.name == "foxglove.Log":
                assert m.message and m.name and m.level in (2, 3), m
            elif schema.name == "foxglove.SceneUpdate":
                assert len(m.entities) > 0 and len(m.deletions) == 0, m
                for e in m.entities:
                    assert e.id and e.frame_id and len(e.arrows) == 0, e
                    assert all(c.size.x > 0 and c.color.a > 0 for c in e.cubes), e
            else:
                raise AssertionError("unexpected schema " + schema.name)
        elif channel.message_encoding == "json":
            assert schema.encoding == "jsonschema"
            assert json.loads(schema.data)["type"] == "object"
            assert isinstance(json.loads(message.data), dict)
        else:
            raise AssertionError("unexpected encoding " + channel.message_encoding)
        decoded += 1
    metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    statistics = reader.get_summary().statistics
print(json.dumps({"counts": counts, "decoded": decoded, "metadata": metadata,
                  "statistics": statistics.message_count}))
"#;

/// A Python that has `mcap` and `mcap_protobuf`, if there is one.
fn python() -> Option<PathBuf> {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/mcap-venv/bin/python3");
    let candidates = std::env::var_os("MCAPLOG_PYTHON")
        .map(PathBuf::from)
        .into_iter()
        .chain([venv, PathBuf::from("python3")]);
    for python in candidates {
        let ok = Command::new(&python)
            .args(["-c", "import mcap, mcap_protobuf"])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false);
        if ok {
            return Some(python);
        }
    }
    None
}

fn python_read(python: &Path, file: &Path) -> serde_json::Value {
    let out = Command::new(python)
        .args(["-c", SCRIPT])
        .arg(file)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "the Python reader failed on {}:\n{}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn check_same(python: &Path, file: &Path) {
    let ours = mcaplog::read_summary(file).unwrap();
    assert!(!ours.recovered);
    let theirs = python_read(python, file);
    let their_counts: BTreeMap<String, u64> =
        serde_json::from_value(theirs["counts"].clone()).unwrap();
    let our_counts: BTreeMap<String, u64> = ours
        .channels
        .iter()
        .filter(|c| c.messages > 0)
        .map(|c| (c.topic.clone(), c.messages))
        .collect();
    assert_eq!(their_counts, our_counts, "{}", file.display());
    assert_eq!(theirs["decoded"], ours.messages);
    assert_eq!(theirs["statistics"], ours.messages);
    let their_metadata: BTreeMap<String, BTreeMap<String, String>> =
        serde_json::from_value(theirs["metadata"].clone()).unwrap();
    let our_metadata: BTreeMap<String, BTreeMap<String, String>> =
        ours.metadata.iter().cloned().collect();
    assert_eq!(their_metadata, our_metadata);
    println!(
        "Python mcap reader: {} messages decoded in {}",
        ours.messages,
        file.display()
    );
}

#[test]
fn the_python_reader_decodes_written_and_recovered_files() {
    let Some(python) = python() else {
        println!(
            "skipped: no Python with the mcap and mcap-protobuf-support packages \
             (python3 -m venv target/mcap-venv && \
             target/mcap-venv/bin/pip install mcap mcap-protobuf-support)"
        );
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("actor-0.mcap");
    write_file(&path, 3);
    check_same(&python, &path);

    // Cut halfway through the file, recovered, then read by the independent reader.
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let recovered = dir.path().join("recovered.mcap");
    let from = mcaplog::recover(&cut, &recovered).unwrap();
    assert!(from.recovered && from.messages > 0, "{from}");
    check_same(&python, &recovered);
}
