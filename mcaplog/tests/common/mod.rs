//! What the tests write: a little of every kind of message, in batches.

#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::Path;

use mcaplog::{
    Color, CubePrimitive, LogLevel, Options, Pose, Quaternion, RunLog, SceneEntity, SceneUpdate,
    Vector3,
};

pub const EPISODES: &str = "/episodes";
pub const HEIGHTMAP: &str = "/heightmap";
pub const SNAPSHOT: &str = "/snapshot";
pub const SCENE: &str = "/scene";

/// Messages of one batch on each topic.
pub const PER_BATCH: [(&str, u64); 5] = [
    (EPISODES, 10),
    (HEIGHTMAP, 3),
    (SNAPSHOT, 1),
    (SCENE, 1),
    (mcaplog::LOG_TOPIC, 2),
];

pub const SIDE: u32 = 112;

/// A 112x112 rgb8 image that looks like a tabletop: a smooth background and a few blocks.
pub fn image(seed: u64) -> Vec<u8> {
    let mut data = Vec::with_capacity((SIDE * SIDE * 3) as usize);
    for y in 0..SIDE {
        for x in 0..SIDE {
            let block = (x / 16 + y / 16 + seed as u32).is_multiple_of(5) as u8;
            let shade = (x + y) as u8 / 2;
            data.extend([shade, 90 + block * 120, 60 + block * 30]);
        }
    }
    data
}

pub fn config() -> BTreeMap<String, String> {
    BTreeMap::from([
        ("run.seed".to_string(), "7".to_string()),
        ("buffer.capacity".to_string(), "10000".to_string()),
    ])
}

/// A scene of `k + 1` boxes, one entity each.
pub fn scene(k: u64, time_ns: u64) -> SceneUpdate {
    let entities = (0..=k)
        .map(|i| SceneEntity {
            timestamp: Some(mcaplog::timestamp(time_ns)),
            frame_id: "world".into(),
            id: format!("object-{i}"),
            lifetime: None,
            frame_locked: false,
            cubes: vec![CubePrimitive {
                pose: Some(Pose {
                    position: Some(Vector3 {
                        x: 0.1 * i as f64,
                        y: 0.0,
                        z: 0.025,
                    }),
                    orientation: Some(Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: 0.0,
                        w: 1.0,
                    }),
                }),
                size: Some(Vector3 {
                    x: 0.05,
                    y: 0.05,
                    z: 0.05,
                }),
                color: Some(Color {
                    r: 0.3,
                    g: 0.5,
                    b: 0.7,
                    a: 1.0,
                }),
            }],
        })
        .collect();
    SceneUpdate { entities }
}

/// Options where only explicit flushes close chunks.
pub fn manual_flush() -> Options {
    Options {
        chunk_size: 64 << 20,
        flush_interval: None,
        ..Options::default()
    }
}

/// Writes batch `k` (see [`PER_BATCH`]).
pub fn write_batch(log: &RunLog, k: u64) {
    for i in 0..10 {
        let episode =
            serde_json::json!({"episode": k * 10 + i, "reward": 0.5, "grasped": i % 2 == 0});
        log.json(EPISODES, &episode).unwrap();
    }
    for i in 0..3 {
        let t = mcaplog::now_ns();
        log.raw_image(HEIGHTMAP, t, SIDE, SIDE, "rgb8", &image(k * 3 + i))
            .unwrap();
    }
    // A tiny PNG-like payload: the format is only carried, not checked.
    log.compressed_image(
        SNAPSHOT,
        mcaplog::now_ns(),
        "png",
        &[0x89, b'P', b'N', b'G'],
    )
    .unwrap();
    let t = mcaplog::now_ns();
    log.scene_update(SCENE, t, &scene(k, t)).unwrap();
    log.log_line(LogLevel::Info, &format!("batch {k} done"))
        .unwrap();
    log.log_line(LogLevel::Warning, "a warning").unwrap();
}

/// Writes `batches` batches, flushing after each, and finishes the file.
pub fn write_file(path: &Path, batches: u64) {
    let log = RunLog::create_with(path, "tester", manual_flush()).unwrap();
    log.json_schema(
        EPISODES,
        "pushgrasp.Episode",
        r#"{"type":"object","properties":{"episode":{"type":"integer"},"reward":{"type":"number"},"grasped":{"type":"boolean"}}}"#,
    )
    .unwrap();
    log.metadata("config", &config()).unwrap();
    for k in 0..batches {
        write_batch(&log, k);
        log.flush().unwrap();
    }
    log.finish().unwrap();
}
