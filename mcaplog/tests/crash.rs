//! Files cut short, as a killed writer leaves them: every complete chunk is recovered, and the
//! recovered file is a sound MCAP file.

mod common;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::*;
use mcaplog::{LogLevel, RunLog, read_summary, recover};

/// Messages per topic in each chunk of a sound file, with the chunk's byte range.
fn chunks(bytes: &[u8]) -> Vec<(u64, u64, BTreeMap<String, u64>)> {
    let summary = mcap::Summary::read(bytes).unwrap().unwrap();
    summary
        .chunk_indexes
        .iter()
        .map(|index| {
            let mut counts = BTreeMap::new();
            for message in summary.stream_chunk(bytes, index).unwrap() {
                *counts
                    .entry(message.unwrap().channel.topic.clone())
                    .or_insert(0) += 1;
            }
            let start = index.chunk_start_offset;
            (start, start + index.chunk_length, counts)
        })
        .collect()
}

/// Reads `path` with the mcap crate's seeking reader, which needs a summary section.
fn indexed_counts(path: &Path) -> BTreeMap<String, u64> {
    let bytes = std::fs::read(path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let mut counts = BTreeMap::new();
    for index in &summary.chunk_indexes {
        for message in summary.stream_chunk(&bytes, index).unwrap() {
            *counts
                .entry(message.unwrap().channel.topic.clone())
                .or_insert(0) += 1;
        }
    }
    counts
}

#[test]
fn a_file_cut_anywhere_keeps_its_complete_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("actor-0.mcap");
    write_file(&path, 4);
    let bytes = std::fs::read(&path).unwrap();
    let chunks = chunks(&bytes);
    let with_messages = chunks.iter().filter(|c| !c.2.is_empty()).count();
    assert_eq!(with_messages, 4, "one chunk per flushed batch");

    // Cut points: inside each chunk (just after its start, halfway, one byte short), at its
    // end, inside the message indexes after it, and inside the summary section and footer.
    let mut cuts = Vec::new();
    for &(start, end, _) in &chunks {
        cuts.extend([start + 1, (start + end) / 2, end - 1, end, end + 3]);
    }
    let len = bytes.len() as u64;
    cuts.extend([len - 40, len - 9, len - 1]);

    let cut_path = dir.path().join("cut.mcap");
    let out_path = dir.path().join("recovered.mcap");
    for cut in cuts {
        std::fs::write(&cut_path, &bytes[..cut as usize]).unwrap();
        let mut expected: BTreeMap<String, u64> = BTreeMap::new();
        for (_, end, counts) in &chunks {
            if *end <= cut {
                for (topic, n) in counts {
                    *expected.entry(topic.clone()).or_insert(0) += n;
                }
            }
        }
        let summary = read_summary(&cut_path).unwrap();
        assert!(summary.recovered, "cut at {cut}: {summary}");
        assert!(!summary.damage.is_empty(), "cut at {cut}");
        let got: BTreeMap<String, u64> = summary
            .channels
            .iter()
            .filter(|c| c.messages > 0)
            .map(|c| (c.topic.clone(), c.messages))
            .collect();
        assert_eq!(got, expected, "cut at {cut} of {len}: {summary}");
        // The config record lies between the chunk of the declared schema and the first
        // chunk of messages.
        let first_messages = chunks.iter().find(|c| !c.2.is_empty()).unwrap().0;
        if cut >= first_messages {
            assert_eq!(summary.metadata("config"), Some(&config()), "cut at {cut}");
        }

        let from = recover(&cut_path, &out_path).unwrap();
        assert_eq!(from.channels, summary.channels, "cut at {cut}");
        let again = read_summary(&out_path).unwrap();
        assert!(!again.recovered, "cut at {cut}: {again}");
        assert_eq!(again.channels, summary.channels, "cut at {cut}");
        assert_eq!(again.metadata, summary.metadata, "cut at {cut}");
        assert_eq!(again.time_span_ns, summary.time_span_ns, "cut at {cut}");
        assert_eq!(indexed_counts(&out_path), expected, "cut at {cut}");
    }
}

#[test]
fn a_file_cut_before_its_first_chunk_has_its_metadata_and_no_messages() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("buffer.mcap");
    write_file(&path, 1);
    let bytes = std::fs::read(&path).unwrap();
    let first_chunk = chunks(&bytes)[0].0 as usize;
    let cut_path = dir.path().join("cut.mcap");
    std::fs::write(&cut_path, &bytes[..first_chunk]).unwrap();
    let summary = read_summary(&cut_path).unwrap();
    assert!(summary.recovered);
    assert_eq!(summary.messages, 0);
    assert_eq!(summary.time_span_ns, None);
    assert_eq!(summary.metadata("process").unwrap()["name"], "tester");

    // Cut inside the magic bytes: not an MCAP file.
    std::fs::write(&cut_path, &bytes[..5]).unwrap();
    let err = read_summary(&cut_path).unwrap_err();
    assert!(matches!(err, mcaplog::Error::NotMcap { .. }), "{err}");
}

const CHILD_ENV: &str = "MCAPLOG_TEST_KILLED_WRITER";

/// In the child (the test binary run again with `CHILD_ENV` set to `busy:PATH` or
/// `burst:PATH`): log with the default options until killed, either as a busy process does (a
/// message every millisecond, an image every 200, so that time rather than size closes the
/// chunks; the time of each message goes to stdout once it is logged), or in one burst of 50
/// messages and then nothing.
fn killed_writer(how: &str) {
    let (how, path) = how.split_once(':').unwrap();
    let log = RunLog::create(path, "actor-0").unwrap();
    log.metadata("config", &config()).unwrap();
    let started = Instant::now();
    if how == "burst" {
        for i in 0..50 {
            log.json("/tick", &serde_json::json!({"i": i})).unwrap();
        }
        std::thread::sleep(Duration::from_secs(60));
        return;
    }
    let image = image(1);
    let mut i = 0u64;
    // Bounded, so that a lost parent leaves no process behind for long.
    while started.elapsed() < Duration::from_secs(60) {
        let t = mcaplog::now_ns();
        if i.is_multiple_of(200) {
            log.raw_image(HEIGHTMAP, t, SIDE, SIDE, "rgb8", &image)
                .unwrap();
            log.log_line(LogLevel::Info, &format!("tick {i}")).unwrap();
        }
        log.json_at("/tick", t, &serde_json::json!({"i": i}))
            .unwrap();
        println!("{t}");
        i += 1;
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Runs `killed_writer` in a child process writing `path`, and kills it with SIGKILL
/// `after` its file appeared. Returns the time of the last message it reported logged.
fn run_and_kill(how: &str, path: &Path, after: Duration) -> u64 {
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args(["child_writer", "--exact", "--test-threads=1", "--nocapture"])
        .env(CHILD_ENV, format!("{how}:{}", path.display()))
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    // The harness's own lines are not numbers and are skipped.
    let reader = std::thread::spawn(move || {
        BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
            .filter_map(|line| line.trim().parse::<u64>().ok())
            .last()
            .unwrap_or(0)
    });
    let waited = Instant::now();
    while std::fs::metadata(path).map(|m| m.len()).unwrap_or(0) == 0 {
        assert!(
            waited.elapsed() < Duration::from_secs(20),
            "the child wrote nothing"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(after);
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    reader.join().unwrap()
}

/// The child's side of the tests below; does nothing as an ordinary test.
#[test]
fn child_writer() {
    if let Ok(how) = std::env::var(CHILD_ENV) {
        killed_writer(&how);
    }
}

#[test]
fn a_writer_killed_with_sigkill_loses_at_most_a_second() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("actor-0.mcap");
    let last_logged = run_and_kill("busy", &path, Duration::from_millis(2500));
    let summary = read_summary(&path).unwrap();
    assert!(summary.recovered, "{summary}");
    assert_eq!(summary.metadata("config"), Some(&config()));
    assert!(summary.messages_on(HEIGHTMAP) > 0, "{summary}");
    let (start, end) = summary.time_span_ns.unwrap();
    assert!(last_logged >= end, "{last_logged} < {end}");
    let lost = (last_logged - end) as f64 * 1e-9;
    let kept = (end - start) as f64 * 1e-9;
    println!("killed writer: kept {kept:.2} s of log, lost the last {lost:.3} s");
    assert!(kept > 1.0, "kept {kept:.2} s: {summary}");
    // One second, and some slack for a loaded machine.
    assert!(lost < 1.5, "lost the last {lost:.3} s: {summary}");

    let out = dir.path().join("recovered.mcap");
    recover(&path, &out).unwrap();
    let again = read_summary(&out).unwrap();
    assert!(!again.recovered);
    assert_eq!(again.channels, summary.channels);
}

#[test]
fn a_writer_killed_while_idle_has_written_everything() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("learner.mcap");
    run_and_kill("burst", &path, Duration::from_millis(1500));
    let summary = read_summary(&path).unwrap();
    assert!(summary.recovered, "{summary}");
    assert_eq!(summary.messages_on("/tick"), 50, "{summary}");
}
