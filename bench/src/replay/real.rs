//! `pushgrasp bench buffer` on real steps: heightmaps of settled scenes the simulator renders
//! (1 to 10 blocks, as an episode clears them), stored the way the buffer role stores them.
//!
//! Each resolution runs in a process of its own, so that its peak resident memory is the
//! buffer's alone: the replay is filled through the buffer's own insert path (episodes of
//! grasps assembled, their observations compressed in parallel, stored), then learner steps
//! at the learner's batch size are timed, the whole way a batch goes (sample, the message
//! encoded and decoded, its observations decompressed, the priorities updated), beside the
//! same with each item's raw transition cloned into the message (how batches were served
//! when the buffer kept observations raw); then the copy a background snapshot takes is
//! timed, a snapshot is written, the buffer dropped, and the snapshot read back. Before that,
//! the codecs the buffer could use are compared on the same observations' planes.

use std::hint::black_box;
use std::time::Instant;

use anyhow::{Context, Result};
use buffer::{BufferConfig, Capacity, ReplayBuffer, Serving};
use experience::observation::planes;
use experience::{BatchItem, Key, Transition};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use serde::de::DeserializeOwned;
use serde_json::{Map, Value};
use sim::{Action, Heightmaps, Primitive, SimConfig};
use wire::BatchMessage;

use crate::status_mb;
use crate::{median, rendered_scene, timed};

/// The learner's batch size (the stage configs').
const LEARNER_BATCH: usize = 4;
/// Distinct scenes rendered; the stored steps cycle through them.
const SCENES: usize = 48;
/// Steps per assembled episode.
const EPISODE: usize = 16;
const LEARNER_STEPS: usize = 2000;

/// The resolutions measured and log2 of the steps stored at each: 2^20 of 112² fit this
/// machine's memory compressed; 224² steps are four times larger.
pub(super) const SIDES: [(usize, u32); 2] = [(112, 20), (224, 17)];

/// Every figure at one resolution, named with its suffix (`_112`, `_real_2p20`).
pub(super) fn figures(side: usize, exponent: u32) -> Result<Map<String, Value>> {
    let config = SimConfig::with_pixel_size(sim::workspace::SIDE / side as f32);
    let scenes = (0..SCENES)
        .map(|i| rendered_scene(&config, 1 + i % 10, i as u64))
        .collect::<Result<Vec<_>>>()?;
    let mut figures = Map::new();
    let mut put = |name: String, value: f64| {
        let rounded = if value >= 100.0 {
            value.round()
        } else {
            (value * 100.0).round() / 100.0
        };
        figures.insert(name, rounded.into());
    };
    let raw = planes(&scenes[0]).len();
    put(format!("raw_bytes_per_step_{side}"), raw as f64);
    let unpack_us = scenes.iter().map(|scene| {
        let packed = experience::PackedObservation::pack(scene);
        timed(|| packed.unpack()).1.as_secs_f64() * 1e6
    });
    put(format!("unpack_us_{side}"), median(unpack_us.collect()));
    for codec in CODECS {
        let (bytes, encode_us, decode_us) = codec_costs(codec, &scenes);
        let name = codec.name();
        put(format!("{name}_bytes_per_step_{side}"), bytes);
        put(format!("{name}_encode_us_{side}"), encode_us);
        put(format!("{name}_decode_us_{side}"), decode_us);
    }

    let steps = 1usize << exponent;
    let suffix = format!("real_2p{exponent}_{side}");
    let (mut buffer, keys, fill_s) = filled(steps, &scenes)?;
    let stored = stored_bytes(&buffer, &keys);
    put(format!("stored_bytes_per_step_{side}"), stored);
    put(format!("compression_ratio_{side}"), raw as f64 / stored);
    put(
        format!("insert_real_steps_per_s_{side}"),
        steps as f64 / fill_s,
    );
    if let Some(rss) = status_mb("self", "VmRSS:") {
        put(format!("rss_mb_{suffix}"), rss);
    }

    let [packed, raw] = learner_steps(&mut buffer, &scenes)?;
    put(format!("learner_steps_per_s_{suffix}"), packed);
    put(format!("learner_steps_per_s_raw_2p{exponent}_{side}"), raw);

    // What a background snapshot holds the buffer up for: the copy it writes.
    let (copy, time) = timed(|| buffer.copy_to_save());
    drop(copy);
    put(
        format!("snapshot_hold_ms_{suffix}"),
        time.as_secs_f64() * 1e3,
    );

    let dir = tempfile::tempdir()?;
    let path = dir.path().join("replay.snap");
    let (saved, time) = timed(|| buffer.save(&path));
    saved?;
    put(format!("snapshot_s_{suffix}"), time.as_secs_f64());
    put(
        format!("snapshot_mb_{suffix}"),
        std::fs::metadata(&path)?.len() as f64 / 1e6,
    );
    drop(buffer);
    let (loaded, time) = timed(|| ReplayBuffer::load(&path));
    let loaded = loaded?;
    anyhow::ensure!(
        loaded.stats().grasp_len == steps,
        "the snapshot read back holds {} steps",
        loaded.stats().grasp_len
    );
    put(format!("resume_s_{suffix}"), time.as_secs_f64());
    if let Some(peak) = status_mb("self", "VmHWM:") {
        put(format!("peak_rss_mb_{suffix}"), peak);
    }
    Ok(figures)
}

/// A buffer of `steps` grasps (episodes of [`EPISODE`] over `scenes`), their keys, and the
/// seconds the inserts took.
fn filled(steps: usize, scenes: &[Heightmaps]) -> Result<(ReplayBuffer, Vec<Key>, f64)> {
    let mut buffer = ReplayBuffer::new(
        BufferConfig {
            capacity: Capacity::Steps(steps),
            ..BufferConfig::default()
        },
        Serving {
            push_reward: policy::PushReward::Change,
            sampled: vec![Primitive::Grasp],
            successors: false,
        },
    )?;
    let mut keys = Vec::with_capacity(steps);
    let mut fill_s = 0.0;
    for episode in 0..(steps / EPISODE) as u64 {
        let transitions: Vec<Transition> = (0..EPISODE)
            .map(|step| grasp(episode, step, scenes))
            .collect();
        let (stored, time) = timed(|| -> Result<Vec<Key>> {
            for t in transitions {
                buffer.add_step(t, Some(1.0))?;
            }
            Ok(buffer.end_episode(episode, Some(1))?)
        });
        keys.extend(stored?);
        fill_s += time.as_secs_f64();
    }
    anyhow::ensure!(keys.len() == steps, "the fill stored {} steps", keys.len());
    Ok((buffer, keys, fill_s))
}

/// Step `step` of a grasp-only episode; its last grasp picks the goal (no relabelled copies).
fn grasp(episode: u64, step: usize, scenes: &[Heightmaps]) -> Transition {
    let i = episode as usize * EPISODE + step;
    let obs = scenes[i % scenes.len()].clone();
    let side = obs.side();
    let last = step + 1 == EPISODE;
    Transition {
        episode,
        step: step as u32,
        goal: 1,
        obs,
        action: Action {
            primitive: Primitive::Grasp,
            rotation: (i % 16) as u8,
            row: (i / side) % side,
            col: i % side,
        },
        reward: if last { 1.0 } else { 0.0 },
        grasped: last.then_some(1),
        next_value: (!last).then_some(0.5),
        next: None,
    }
}

/// Mean compressed bytes per stored step.
fn stored_bytes(buffer: &ReplayBuffer, keys: &[Key]) -> f64 {
    let total: usize = keys
        .iter()
        .filter_map(|key| buffer.replay().get(key))
        .map(|t| t.obs.compressed().len())
        .sum();
    total as f64 / keys.len() as f64
}

/// Learner steps/s, medians, a batch's whole way: [packed (sample, message encoded and
/// decoded, unpacked, priorities updated), raw (sample, raw clones in the message encoded and
/// decoded, priorities updated)].
fn learner_steps(buffer: &mut ReplayBuffer, scenes: &[Heightmaps]) -> Result<[f64; 2]> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut timings = [Vec::new(), Vec::new()];
    let mut bytes = Vec::new();
    for i in 0..2 * LEARNER_STEPS {
        let packed = i % 2 == 0;
        let start = Instant::now();
        let batch = buffer.sample(Primitive::Grasp, LEARNER_BATCH, &mut rng)?;
        let keys: Vec<Key> = batch.items.iter().map(|item| item.key).collect();
        let items = batch.to_owned_items();
        if packed {
            let message = send_and_receive(BatchMessage { request: 0, items }, &mut bytes)?;
            black_box(buffer::unpack(&message.items)?);
        } else {
            let raw: Vec<BatchItem> = items
                .into_iter()
                .map(|item| BatchItem {
                    key: item.key,
                    weight: item.weight,
                    transition: item
                        .transition
                        .map_obs(|_| scenes[item.key.slot as usize % scenes.len()].clone()),
                })
                .collect();
            black_box(send_and_receive(raw, &mut bytes)?);
        }
        let updates: Vec<(Key, f64)> = keys
            .into_iter()
            .map(|key| (key, 2.0 * rng.random::<f64>()))
            .collect();
        buffer.update_priorities(&updates)?;
        timings[usize::from(!packed)].push(start.elapsed().as_secs_f64());
    }
    Ok(timings.map(|t| 1.0 / median(t)))
}

/// `message` encoded into `bytes` as the buffer's outbox does and decoded back as the
/// learner's inbox does.
fn send_and_receive<M: Serialize + DeserializeOwned>(message: M, bytes: &mut Vec<u8>) -> Result<M> {
    bytes.clear();
    let encoded = postcard::to_extend(&message, std::mem::take(bytes))?;
    let back = postcard::from_bytes(&encoded)?;
    *bytes = encoded;
    Ok(back)
}

/// A codec the buffer could store observations with.
#[derive(Clone, Copy)]
enum Codec {
    Zstd(i32),
    Lz4,
}

const CODECS: [Codec; 4] = [Codec::Zstd(1), Codec::Zstd(3), Codec::Zstd(9), Codec::Lz4];

impl Codec {
    fn name(self) -> String {
        match self {
            Codec::Zstd(level) => format!("zstd{level}"),
            Codec::Lz4 => "lz4".into(),
        }
    }

    fn encode(self, bytes: &[u8]) -> Vec<u8> {
        match self {
            Codec::Zstd(level) => zstd::bulk::compress(bytes, level).expect("zstd compresses"),
            Codec::Lz4 => lz4_flex::block::compress(bytes),
        }
    }

    fn decode(self, bytes: &[u8], len: usize) -> Vec<u8> {
        match self {
            Codec::Zstd(_) => zstd::bulk::decompress(bytes, len).expect("zstd decodes its own"),
            Codec::Lz4 => lz4_flex::block::decompress(bytes, len).expect("lz4 decodes its own"),
        }
    }
}

/// Mean bytes per step, median encode and decode microseconds of one step's planes.
fn codec_costs(codec: Codec, scenes: &[Heightmaps]) -> (f64, f64, f64) {
    let (mut bytes, mut encode, mut decode) = (0, Vec::new(), Vec::new());
    for scene in scenes {
        let planes = planes(scene);
        let (packed, time) = timed(|| codec.encode(&planes));
        encode.push(time.as_secs_f64() * 1e6);
        let (back, time) = timed(|| codec.decode(&packed, planes.len()));
        decode.push(time.as_secs_f64() * 1e6);
        assert_eq!(back, planes, "{} round-trips", codec.name());
        bytes += packed.len();
    }
    (
        bytes as f64 / scenes.len() as f64,
        median(encode),
        median(decode),
    )
}

/// Runs [`figures`] for each of [`SIDES`] in a child process (`--real-side`), each its own
/// peak memory.
pub(super) fn in_children(json_figures: &mut Map<String, Value>) -> Result<()> {
    let exe = std::env::current_exe().context("finding this executable")?;
    for (side, _) in SIDES {
        let output = std::process::Command::new(&exe)
            .args([
                "bench",
                "buffer",
                "--json",
                "--real-side",
                &side.to_string(),
            ])
            .stderr(std::process::Stdio::inherit())
            .output()
            .context("running the real-step figures")?;
        anyhow::ensure!(
            output.status.success(),
            "the real-step figures at {side} failed"
        );
        let line = String::from_utf8_lossy(&output.stdout);
        let Value::Object(figures) = serde_json::from_str(line.trim())? else {
            anyhow::bail!("the real-step figures at {side} are not a JSON object");
        };
        json_figures.extend(figures);
    }
    Ok(())
}
