//! Files written by `RunLog` read back with the counts, times and metadata that went in.

mod common;

use std::time::Duration;

use common::*;
use mcaplog::{Error, LogLevel, Options, RunLog, read_summary, recover};

#[test]
fn a_finished_file_reads_back_from_its_summary() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("learner.mcap");
    let before = mcaplog::now_ns();
    write_file(&path, 3);
    let after = mcaplog::now_ns();

    let summary = read_summary(&path).unwrap();
    assert!(!summary.recovered, "{summary}");
    assert!(summary.damage.is_empty(), "{summary}");
    for (topic, n) in PER_BATCH {
        assert_eq!(summary.messages_on(topic), 3 * n, "{topic}\n{summary}");
    }
    assert_eq!(
        summary.messages,
        3 * PER_BATCH.iter().map(|p| p.1).sum::<u64>()
    );
    let (start, end) = summary.time_span_ns.unwrap();
    assert!(before <= start && start <= end && end <= after);

    let process = summary.metadata(mcaplog::PROCESS_METADATA).unwrap();
    assert_eq!(process["name"], "tester");
    assert_eq!(process["pid"], std::process::id().to_string());
    assert_eq!(summary.metadata("config"), Some(&config()));

    let schema = |topic: &str| {
        let c = summary.channels.iter().find(|c| c.topic == topic).unwrap();
        (c.schema_name.as_str(), c.message_encoding.as_str())
    };
    assert_eq!(schema(EPISODES), ("pushgrasp.Episode", "json"));
    assert_eq!(schema(HEIGHTMAP), ("foxglove.RawImage", "protobuf"));
    assert_eq!(schema(SNAPSHOT), ("foxglove.CompressedImage", "protobuf"));
    assert_eq!(schema(mcaplog::LOG_TOPIC), ("foxglove.Log", "protobuf"));
    assert!(summary.to_string().contains("/heightmap"));
}

#[test]
fn messages_decode_with_the_mcap_crate() {
    use prost::Message as _;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("actor-0.mcap");
    write_file(&path, 2);
    let bytes = std::fs::read(&path).unwrap();
    let mut images = 0;
    let mut last_episode = None;
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        match message.channel.topic.as_str() {
            HEIGHTMAP => {
                let image = mcaplog::RawImage::decode(&*message.data).unwrap();
                assert_eq!(
                    (image.width, image.height, image.step),
                    (SIDE, SIDE, 3 * SIDE)
                );
                assert_eq!(image.encoding, "rgb8");
                assert_eq!(image.data.len(), (3 * SIDE * SIDE) as usize);
                let t = image.timestamp.unwrap();
                assert_eq!(
                    t.seconds as u64 * 1_000_000_000 + t.nanos as u64,
                    message.log_time
                );
                images += 1;
            }
            EPISODES => {
                let v: serde_json::Value = serde_json::from_slice(&message.data).unwrap();
                last_episode = v["episode"].as_u64();
                let schema = message.channel.schema.as_ref().unwrap();
                assert_eq!(schema.encoding, "jsonschema");
            }
            mcaplog::LOG_TOPIC => {
                let line = mcaplog::Log::decode(&*message.data).unwrap();
                assert_eq!(line.name, "tester");
                assert!(
                    line.level == LogLevel::Info as i32 || line.level == LogLevel::Warning as i32
                );
            }
            _ => {}
        }
    }
    assert_eq!(images, 6);
    assert_eq!(last_episode, Some(19));
}

#[test]
fn protobuf_messages_read_back_as_written_with_their_times() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("actor-0.mcap");
    let log = RunLog::create_with(&path, "tester", manual_flush()).unwrap();
    for k in 0..3 {
        log.scene_update(SCENE, 1_000 + k, &scene(k, 1_000 + k))
            .unwrap();
    }
    log.finish().unwrap();
    let scenes = mcaplog::proto_messages::<mcaplog::SceneUpdate>(&path, SCENE).unwrap();
    let expected: Vec<_> = (0..3).map(|k| (1_000 + k, scene(k, 1_000 + k))).collect();
    assert_eq!(scenes, expected);
    assert!(
        mcaplog::proto_messages::<mcaplog::RawImage>(&path, HEIGHTMAP)
            .unwrap()
            .is_empty()
    );
}

#[test]
fn a_disabled_log_takes_everything_and_writes_nothing() {
    let log = RunLog::disabled("tester");
    assert!(!log.enabled());
    write_batch(&log, 0);
    log.metadata("config", &config()).unwrap();
    log.flush().unwrap();
    assert_eq!(log.path(), std::path::Path::new(""));
    log.finish().unwrap();
}

#[test]
fn sequences_count_up_per_channel() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("buffer.mcap");
    write_file(&path, 2);
    let bytes = std::fs::read(&path).unwrap();
    let mut next = std::collections::HashMap::new();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let expected = next.entry(message.channel.id).or_insert(0u32);
        assert_eq!(message.sequence, *expected, "{}", message.channel.topic);
        *expected += 1;
    }
}

#[test]
fn a_permissive_schema_names_undeclared_json_topics() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("launcher.mcap");
    let log = RunLog::create(&path, "launcher").unwrap();
    log.json("/learner/stats", &serde_json::json!({"loss": 0.25}))
        .unwrap();
    log.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let channel = summary.channels.values().next().unwrap();
    let schema = channel.schema.as_ref().unwrap();
    assert_eq!(schema.name, "learner/stats");
    let schema: serde_json::Value = serde_json::from_slice(&schema.data).unwrap();
    assert_eq!(schema["type"], "object");
    assert_eq!(schema["title"], "/learner/stats");
}

#[test]
fn misuse_is_refused_with_the_topic_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("actor-1.mcap");
    let log = RunLog::create(&path, "actor-1").unwrap();
    let err = log.json("/x", &3.5).unwrap_err();
    assert!(err.to_string().contains("must be an object"), "{err}");
    log.json("/x", &serde_json::json!({"a": 1})).unwrap();
    let err = log.raw_image("/x", 0, 2, 2, "mono8", &[0; 4]).unwrap_err();
    assert!(err.to_string().contains("carries JSON messages"), "{err}");
    let err = log.raw_image("/img", 0, 2, 2, "rgb8", &[0; 4]).unwrap_err();
    assert!(err.to_string().contains("has 12 bytes, not 4"), "{err}");
    let err = log.raw_image("/img", 0, 2, 2, "yuv9", &[0; 4]).unwrap_err();
    assert!(
        err.to_string().contains("unsupported image encoding"),
        "{err}"
    );
    let err = log.json_schema("/x", "X", "{}").unwrap_err();
    assert!(err.to_string().contains("already has a channel"), "{err}");
    let err = log.json_schema("/y", "Y", "{nope").unwrap_err();
    assert!(err.to_string().contains("not JSON"), "{err}");
    assert!(err.to_string().contains("actor-1.mcap"), "{err}");
    log.finish().unwrap();
    // The refused messages left the file sound.
    let summary = read_summary(&path).unwrap();
    assert_eq!(summary.messages, 1);
    assert!(!summary.recovered);
}

#[test]
fn bad_input_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    let err = read_summary(&empty).unwrap_err();
    assert!(matches!(err, Error::Empty { .. }), "{err}");
    assert!(err.to_string().contains("empty.mcap"), "{err}");

    let text = dir.path().join("notes.txt");
    std::fs::write(&text, b"this is not a log file at all").unwrap();
    let err = read_summary(&text).unwrap_err();
    assert!(matches!(err, Error::NotMcap { .. }), "{err}");
    assert!(err.to_string().contains("notes.txt"), "{err}");
    let err = recover(&text, dir.path().join("out.mcap")).unwrap_err();
    assert!(matches!(err, Error::NotMcap { .. }), "{err}");

    let missing = dir.path().join("missing.mcap");
    let err = read_summary(&missing).unwrap_err();
    assert!(err.to_string().contains("missing.mcap"), "{err}");

    let sound = dir.path().join("sound.mcap");
    write_file(&sound, 1);
    let err = recover(&sound, &sound).unwrap_err();
    assert!(matches!(err, Error::SameFile { .. }), "{err}");
}

#[test]
fn recovering_a_sound_file_copies_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("learner.mcap");
    let copy = dir.path().join("copy.mcap");
    write_file(&path, 2);
    let from = recover(&path, &copy).unwrap();
    assert!(!from.recovered, "{from}");
    let original = read_summary(&path).unwrap();
    let copied = read_summary(&copy).unwrap();
    assert_eq!(copied.channels, original.channels);
    assert_eq!(copied.metadata, original.metadata);
    assert_eq!(copied.time_span_ns, original.time_span_ns);
    assert_eq!(from.channels, original.channels);
}

#[test]
fn the_background_flush_writes_an_idle_log_within_the_interval() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("idle.mcap");
    let log = RunLog::create_with(
        &path,
        "idle",
        mcaplog::Options {
            flush_interval: Some(std::time::Duration::from_millis(200)),
            ..mcaplog::Options::default()
        },
    )
    .unwrap();
    log.json("/status", &serde_json::json!({"fill": 3}))
        .unwrap();
    let size = std::fs::metadata(&path).unwrap().len();
    std::thread::sleep(std::time::Duration::from_millis(400));
    // Nothing else was logged, yet the message is in the file.
    let later = std::fs::metadata(&path).unwrap().len();
    assert!(later > size, "{size} -> {later}");
    let summary = read_summary(&path).unwrap();
    assert!(summary.recovered);
    assert_eq!(summary.messages_on("/status"), 1);
    drop(log);
    assert!(!read_summary(&path).unwrap().recovered);
}

#[test]
fn a_long_log_goes_on_in_segments_each_a_whole_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("actor-0.mcap");
    let options = Options {
        segment_every: Some(Duration::from_millis(100)),
        ..manual_flush()
    };
    let log = RunLog::create_with(&path, "tester", options).unwrap();
    log.json_schema(EPISODES, "pushgrasp.Episode", r#"{"type":"object"}"#)
        .unwrap();
    log.metadata("config", &config()).unwrap();
    for k in 0..4 {
        write_batch(&log, k);
        std::thread::sleep(Duration::from_millis(120));
    }
    log.finish().unwrap();

    // Each batch came after its segment's time was up: four files at least.
    let files = mcaplog::segments(&path);
    assert!(files.len() >= 4, "{files:?}");
    assert_eq!(files[1], dir.path().join("actor-0.1.mcap"));
    let mut episodes = Vec::new();
    let mut sequences = Vec::new();
    for file in &files {
        let summary = read_summary(file).unwrap();
        assert!(!summary.recovered && summary.damage.is_empty(), "{summary}");
        assert_eq!(
            summary.metadata(mcaplog::PROCESS_METADATA).unwrap()["name"],
            "tester"
        );
        assert_eq!(summary.metadata("config"), Some(&config()));
        for channel in summary.channels.iter().filter(|c| c.topic == EPISODES) {
            assert_eq!(channel.schema_name, "pushgrasp.Episode", "{summary}");
        }
        for episode in mcaplog::json_messages(file, EPISODES).unwrap() {
            episodes.push(episode["episode"].as_u64().unwrap());
        }
        let bytes = std::fs::read(file).unwrap();
        for message in mcap::MessageStream::new(&bytes).unwrap() {
            let message = message.unwrap();
            if message.channel.topic == EPISODES {
                sequences.push(u64::from(message.sequence));
            }
        }
    }
    // Every message once, in order, its topic's sequence numbers going on across files.
    assert_eq!(episodes, (0..40).collect::<Vec<_>>());
    assert_eq!(sequences, episodes);
    let newest = mcaplog::newest_json_message(&path, EPISODES)
        .unwrap()
        .unwrap();
    assert_eq!(newest["episode"], 39);

    // A new log of the same name is not followed by the old one's segments.
    RunLog::create(&path, "tester").unwrap().finish().unwrap();
    assert_eq!(mcaplog::segments(&path), vec![path.clone()]);
}

#[test]
fn a_continued_log_keeps_what_the_earlier_process_wrote_and_goes_on_after_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("launcher.mcap");
    // The first process died mid-write: its file ends in a partial record.
    write_file(&path, 2);
    let cut = std::fs::metadata(&path).unwrap().len() - 100;
    let file = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    file.set_len(cut).unwrap();
    let earlier = std::fs::read(&path).unwrap();

    let log = RunLog::continue_with(&path, "resumed", manual_flush()).unwrap();
    write_batch(&log, 2);
    log.finish().unwrap();

    assert_eq!(
        std::fs::read(&path).unwrap(),
        earlier,
        "the earlier file changed"
    );
    let files = mcaplog::segments(&path);
    assert_eq!(
        files,
        vec![path.clone(), dir.path().join("launcher.1.mcap")]
    );
    let continued = read_summary(&files[1]).unwrap();
    assert!(!continued.recovered, "{continued}");
    assert_eq!(
        continued.metadata(mcaplog::PROCESS_METADATA).unwrap()["name"],
        "resumed"
    );
    // Every earlier message the cut left whole, then the new ones.
    let episodes: Vec<u64> = files
        .iter()
        .flat_map(|file| mcaplog::json_messages(file, EPISODES).unwrap())
        .map(|episode| episode["episode"].as_u64().unwrap())
        .collect();
    assert_eq!(episodes, (0..30).collect::<Vec<_>>());

    // Continuing where there is no log yet starts one.
    let fresh = dir.path().join("buffer.mcap");
    RunLog::continue_with(&fresh, "buffer", manual_flush())
        .unwrap()
        .finish()
        .unwrap();
    assert_eq!(mcaplog::segments(&fresh), vec![fresh.clone()]);
}
