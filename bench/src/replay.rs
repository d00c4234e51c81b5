//! `pushgrasp bench buffer`: the prioritised replay's insert rate and learner-step rate (sample
//! a batch with importance-sampling weights, then update its priorities) at two capacities,
//! beside cpprb's `PrioritizedReplayBuffer` run the same way when Python has it; then the
//! same on real steps at 112² and 224² ([`real`]): bytes stored per step, compression,
//! memory, snapshot and resume.
//!
//! The small-item figures measure the replay's bookkeeping: the ring, the sum tree,
//! stratified sampling, the importance-sampling weights and the priority updates. The stored
//! transitions are real [`StoredTransition`]s, but on the coarsest grid the simulator allows
//! (8 x 8 pixels), so that 2^21 of them fit in memory; the replay never reads an observation
//! while sampling (a batch holds references), so the size of the maps does not enter the
//! learner-step figure. cpprb runs with small observations likewise (one 8 x 8 byte map each
//! for `obs` and `next_obs`); it copies the sampled rows into its batch, ours does not. Both
//! insert chunks of 1,024 items per call.

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use buffer::{BufferConfig, PrioritizedReplay};
use clap::Args;
use experience::{StoredTransition, Transition};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{Map, Value};
use sim::{Action, Heightmaps, PixelGrid, Primitive};

mod real;

use super::python::{default_python, script_figures};
use super::{median, print_figures, status_mb, timed};

/// Items per sampled batch, ours and cpprb's.
const BATCH: usize = 512;
/// log2 of the capacities measured.
const CAPACITY_EXPONENTS: [u32; 2] = [17, 21];
/// Transitions built (untimed) and then inserted (timed) at a time, ours with one
/// `insert_many`, cpprb's with one `add`.
const INSERT_CHUNK: usize = 1024;
/// Pixels per side of the stored observations: the coarsest grid the simulator allows.
const OBS_SIDE: usize = 8;
/// Learner steps run before the timed ones.
const WARM_UP_STEPS: usize = 20;

#[derive(Args)]
pub struct BufferBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Timed learner steps at each capacity (the median step is reported).
    #[arg(long, default_value_t = 2000)]
    steps: usize,
    /// The Python that runs cpprb beside ours [default: target/bench-venv/bin/python3 when
    /// it exists, else python3].
    #[arg(long)]
    python: Option<PathBuf>,
    /// Leave cpprb out.
    #[arg(long)]
    no_cpprb: bool,
    /// Leave out the figures on real steps (several minutes, up to ~10 GB of memory).
    #[arg(long)]
    no_real: bool,
    /// Only the real-step figures at this side (what each child process measures).
    #[arg(long, hide = true)]
    real_side: Option<usize>,
}

pub fn bench_buffer(args: &BufferBenchArgs) -> Result<()> {
    if let Some(side) = args.real_side {
        let (_, exponent) = real::SIDES
            .into_iter()
            .find(|(s, _)| *s == side)
            .with_context(|| format!("no real-step figures at side {side}"))?;
        return print_figures(&Value::Object(real::figures(side, exponent)?), true);
    }
    let steps = args.steps.max(1);
    let mut figures = Map::new();
    figures.insert("batch".into(), BATCH.into());
    figures.insert("obs_side".into(), OBS_SIDE.into());
    let mut ours = Vec::new();
    for exp in CAPACITY_EXPONENTS {
        let measured = bench_ours(1 << exp, steps)?;
        let mut put = |name: &str, value: f64| {
            figures.insert(format!("{name}_2p{exp}"), (value.round() as u64).into());
        };
        put("insert_per_s", measured.insert_per_s);
        put("learner_steps_per_s", measured.learner_steps_per_s);
        put("sample_us", measured.sample_us);
        put("update_us", measured.update_us);
        if let Some(rss) = measured.rss_mb {
            put("rss_mb", rss);
        }
        ours.push((exp, measured.learner_steps_per_s));
    }
    if let Some(peak) = status_mb("self", "VmHWM:") {
        figures.insert("peak_rss_mb".into(), (peak.round() as u64).into());
    }

    if args.no_cpprb {
        figures.insert("cpprb".into(), "not run (--no-cpprb)".into());
    } else {
        let python = args.python.clone().unwrap_or_else(default_python);
        match run_cpprb(&python, steps) {
            Ok(reference) => {
                for (name, value) in &reference {
                    figures.insert(format!("cpprb_{name}"), value.clone());
                }
                for (exp, learner_steps) in ours {
                    let key = format!("learner_steps_per_s_2p{exp}");
                    if let Some(theirs) = reference.get(&key).and_then(Value::as_f64) {
                        let ratio = (learner_steps / theirs * 100.0).round() / 100.0;
                        figures.insert(format!("learner_steps_vs_cpprb_2p{exp}"), ratio.into());
                    }
                }
            }
            Err(why) => {
                eprintln!(
                    "cpprb was not run ({why:#}); to run it beside ours:\n  \
                     python3 -m venv target/bench-venv && \
                     target/bench-venv/bin/python3 -m pip install cpprb"
                );
                figures.insert("cpprb".into(), format!("not run: {why:#}").into());
            }
        }
    }
    if !args.no_real {
        real::in_children(&mut figures)?;
    }
    print_figures(&Value::Object(figures), args.json)
}

/// Our figures at one capacity.
struct OurFigures {
    /// Over all inserts: filling the ring and overwriting an eighth of it.
    insert_per_s: f64,
    /// Of the median learner step.
    learner_steps_per_s: f64,
    /// Medians of the step's two parts: the sample (with weights), the priority updates.
    sample_us: f64,
    update_us: f64,
    /// The process's resident memory while the replay is full.
    rss_mb: Option<f64>,
}

/// Fills a replay of `capacity` grasp slots and overwrites an eighth of it, then times
/// learner steps.
fn bench_ours(capacity: usize, steps: usize) -> Result<OurFigures> {
    let config = BufferConfig {
        capacity: buffer::Capacity::Steps(capacity),
        ..BufferConfig::default()
    };
    let mut replay = PrioritizedReplay::new(&config)?;
    let grid = PixelGrid::new(sim::workspace::SIDE / OBS_SIDE as f32)?;
    let mut rng = ChaCha8Rng::seed_from_u64(capacity as u64);

    let total = capacity + capacity / 8;
    let mut insert_time = Duration::ZERO;
    let mut chunk = Vec::with_capacity(INSERT_CHUNK);
    let mut made = 0;
    while made < total {
        let n = INSERT_CHUNK.min(total - made);
        chunk.extend(
            (made..made + n).map(|i| (transition(grid, i as u64), Some(2.0 * rng.random::<f64>()))),
        );
        made += n;
        let items = std::mem::take(&mut chunk);
        let (inserted, time) = timed(|| replay.insert_many(items));
        inserted?;
        insert_time += time;
    }
    let rss = status_mb("self", "VmRSS:");

    // A learner step: sample a batch, read its keys and weights, update its priorities.
    // Returns the times of the sample and of the updates.
    let mut keys = Vec::with_capacity(BATCH);
    let mut step = |rng: &mut ChaCha8Rng| -> Result<[f64; 2]> {
        let start = Instant::now();
        let batch = replay.sample(Primitive::Grasp, BATCH, rng)?;
        keys.clear();
        keys.extend(batch.items.iter().map(|item| item.key));
        black_box(batch.items.iter().map(|item| item.weight).sum::<f32>());
        drop(batch);
        let sampled = Instant::now();
        for key in &keys {
            replay.update_priority(key, 2.0 * rng.random::<f64>())?;
        }
        Ok([sampled - start, sampled.elapsed()].map(|d| d.as_secs_f64()))
    };
    for _ in 0..WARM_UP_STEPS {
        step(&mut rng)?;
    }
    let (mut whole, mut sample, mut update) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..steps {
        let [s, u] = step(&mut rng)?;
        whole.push(s + u);
        sample.push(s * 1e6);
        update.push(u * 1e6);
    }
    Ok(OurFigures {
        insert_per_s: total as f64 / insert_time.as_secs_f64(),
        learner_steps_per_s: 1.0 / median(whole),
        sample_us: median(sample),
        update_us: median(update),
        rss_mb: rss,
    })
}

/// A grasp step on the coarse grid, packed as the buffer stores it; `i` varies what a
/// learner would read.
fn transition(grid: PixelGrid, i: u64) -> StoredTransition {
    let mut obs = Heightmaps::new(grid);
    let pixels = obs.ids.len();
    obs.ids[i as usize % pixels] = 1;
    obs.height[i as usize % pixels] = 0.025;
    experience::observation::store(Transition {
        episode: i / 8,
        step: (i % 8) as u32,
        goal: 1,
        obs,
        action: Action {
            primitive: Primitive::Grasp,
            rotation: (i % 16) as u8,
            row: (i as usize / OBS_SIDE) % OBS_SIDE,
            col: i as usize % OBS_SIDE,
        },
        reward: if i.is_multiple_of(3) { 1.0 } else { 0.0 },
        grasped: i.is_multiple_of(3).then_some(1),
        next_value: Some(0.5),
        next: None,
    })
}

/// Runs [`CPPRB_SCRIPT`]: its figures, named as ours (`insert_per_s_2p17`, ...), with
/// `version` and `peak_rss_mb`.
fn run_cpprb(python: &Path, steps: usize) -> Result<Map<String, Value>> {
    let capacities = CAPACITY_EXPONENTS
        .map(|e| (1usize << e).to_string())
        .join(",");
    let args = [
        capacities,
        BATCH.to_string(),
        steps.to_string(),
        WARM_UP_STEPS.to_string(),
        INSERT_CHUNK.to_string(),
        OBS_SIDE.to_string(),
    ];
    script_figures(python, CPPRB_IMPORTS, CPPRB_SCRIPT, &args)
}

const CPPRB_IMPORTS: &str = "import numpy as np
from cpprb import PrioritizedReplayBuffer
from importlib.metadata import version";

/// cpprb's side, run the way ours is: inserts with priorities in chunks until the buffer is
/// full and an eighth more, then learner steps (sample with beta 0.4, update the batch's
/// priorities), the median step timed. Arguments: capacities (comma-separated), batch, timed
/// steps, warm-up steps, insert chunk, observation side. Prints one JSON object.
const CPPRB_SCRIPT: &str = r#"
capacities = [int(c) for c in sys.argv[1].split(",")]
batch, steps, warm_up, chunk, side = (int(a) for a in sys.argv[2:7])
figures = {"version": version("cpprb")}
for capacity in capacities:
    rng = np.random.default_rng(capacity)
    obs = {"shape": (side, side), "dtype": np.uint8}
    env = {"obs": obs, "act": {"shape": 1, "dtype": np.int64}, "rew": {},
           "next_obs": obs, "done": {}}
    rb = PrioritizedReplayBuffer(capacity, env, alpha=0.6, eps=1e-3)
    maps = rng.integers(0, 11, size=(chunk, side, side), dtype=np.uint8)
    act = rng.integers(0, side * side * 16, size=(chunk, 1))
    rew = rng.random(chunk, dtype=np.float32)
    done = np.zeros(chunk, dtype=np.float32)
    total, made, elapsed = capacity + capacity // 8, 0, 0.0
    while made < total:
        n = min(chunk, total - made)
        priorities = 2.0 * rng.random(n)
        start = time.perf_counter()
        rb.add(obs=maps[:n], act=act[:n], rew=rew[:n], next_obs=maps[:n], done=done[:n],
               priorities=priorities)
        elapsed += time.perf_counter() - start
        made += n
    times = []
    for i in range(warm_up + steps):
        start = time.perf_counter()
        sample = rb.sample(batch, beta=0.4)
        rb.update_priorities(sample["indexes"], 2.0 * rng.random(batch))
        if i >= warm_up:
            times.append(time.perf_counter() - start)
    times.sort()
    exp = capacity.bit_length() - 1
    figures[f"insert_per_s_2p{exp}"] = round(total / elapsed)
    figures[f"learner_steps_per_s_2p{exp}"] = round(1.0 / times[len(times) // 2])
    del rb
try:
    # The peak of this process alone (getrusage's would include what the parent had).
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                figures["peak_rss_mb"] = round(int(line.split()[1]) / 1024)
except OSError:
    pass
print(json.dumps(figures))
"#;
