//! `pushgrasp bench`: figures for the hot paths, each beside its floor measured in the same
//! run (for the simulator, one bare rapier step).

use std::time::{Duration, Instant};

use anyhow::Result;
use clap::{Args, Subcommand};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rundir::backend::Backend;
use runtime::stopwatch::status_mb;
use serde::Serialize;
use sim::rapier3d::prelude::{Pose, Rotation, Vector};
use sim::{Action, Camera, Heightmaps, Primitive, ROTATIONS, ShapeKind, SimConfig, Tabletop};

use sim::MaskShape;

mod e2e;
mod hosts;
mod logging;
mod peer;
mod python;
mod replay;
mod soak;
mod thread_cpu;
mod transport;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// The simulator: scene settling, heightmaps, primitives, grasp and push quality.
    Sim(SimBenchArgs),
    /// The Q-networks: inference on all rotations, training steps, FLOP rates beside the
    /// backend's matmul peak; onnxruntime's inference, numpy's sgemm and PyTorch's training
    /// step of the same nets beside them.
    Learner(LearnerBenchArgs),
    /// The prioritised replay: inserts and learner steps (sample with importance-sampling
    /// weights, update priorities) at 2^17 and 2^21 slots, beside cpprb when Python has it;
    /// then real steps at 112² and 224²: compression, memory, snapshot and resume.
    Buffer(replay::BufferBenchArgs),
    /// The whole system: actions/s of real training runs with 1, 2 and 4 actor processes,
    /// and the learner's updates/s.
    E2e(e2e::E2eBenchArgs),
    /// The MCAP logs: actor actions/s with logging on and off (same invocation), and the
    /// size of a run's logs at 224 x 224 per 1000 episodes.
    Logging(logging::LoggingBenchArgs),
    /// The transport: 0.5 MB steps from 1, 2 and 4 processes to one subscriber through
    /// iceoryx2 shared memory, beside Unix sockets and memcpy; iceoryx2's latency.
    Transport(transport::TransportBenchArgs),
    /// The link between hosts: real-size steps through Zenoh over loopback beside a plain
    /// TCP socket, and the weights reaching 4 joined hosts.
    Hosts(hosts::HostsBenchArgs),
    /// Memory over a long run: every process's resident memory while a stage-3 run goes on
    /// for 20 minutes after its replay is full, and its growth beside a 5% bound.
    Soak(soak::SoakBenchArgs),
}

#[derive(Args)]
pub struct LearnerBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Repetitions of each timed figure (medians are reported).
    #[arg(long, default_value_t = 10)]
    reps: usize,
    /// Time the nets of this run config's `[net]` (default: the library's default shape).
    #[arg(long)]
    config: Option<std::path::PathBuf>,
    /// The Python that runs the peers beside ours (onnxruntime and numpy; PyTorch where
    /// installed) [default: target/bench-venv/bin/python3 when it exists, else python3].
    #[arg(long)]
    python: Option<std::path::PathBuf>,
    /// Leave the peers out.
    #[arg(long)]
    no_peer: bool,
    /// The backend timed, `cpu` or `wgpu` (a wgpu build); on wgpu, the same nets on the CPU
    /// give `max_rel_diff_vs_cpu` and the CPU's training step beside it.
    #[arg(long, default_value_t = Backend::Cpu)]
    backend: Backend,
    /// Heightmap sides timed (pixels; the workspace is divided into side x side).
    #[arg(long, value_delimiter = ',', default_values_t = [112, 224])]
    sides: Vec<u32>,
}

#[derive(Args)]
pub struct SimBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Repetitions of each timed figure (medians are reported).
    #[arg(long, default_value_t = 20)]
    reps: usize,
    /// Seeded trials of each quality figure.
    #[arg(long, default_value_t = 40)]
    trials: usize,
}

/// The simulator's figures; times are medians.
#[derive(Serialize)]
struct SimFigures {
    settle_ms: f64,
    heightmap_224_ms: f64,
    heightmap_112_ms: f64,
    push_ms: f64,
    grasp_ms: f64,
    action_cycle_ms: f64,
    rapier_step_us: f64,
    /// Share of the primitives' time spent outside rapier's step.
    primitive_outside_step_share: f64,
    physics_steps_per_push: f64,
    physics_steps_per_grasp: f64,
    isolated_cube_grasp_success: f64,
    isolated_cube_grasps: usize,
    clutter_grasp_success: f64,
    clutter_grasps: usize,
    empty_table_grasp_success: f64,
    push_displacement_m: f64,
}

pub fn run(command: BenchCommand) -> Result<()> {
    match command {
        BenchCommand::Sim(args) => bench_sim(&args),
        BenchCommand::Learner(args) => bench_learner(&args),
        BenchCommand::Buffer(args) => replay::bench_buffer(&args),
        BenchCommand::E2e(args) => e2e::bench_e2e(&args),
        BenchCommand::Logging(args) => logging::bench_logging(&args),
        BenchCommand::Transport(args) => transport::bench_transport(&args),
        BenchCommand::Hosts(args) => hosts::bench_hosts(&args),
        BenchCommand::Soak(args) => soak::bench_soak(&args),
    }
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// The heightmaps of a settled random scene of `objects` blocks: what an actor observes.
fn rendered_scene(config: &SimConfig, objects: usize, seed: u64) -> Result<Heightmaps> {
    let (tabletop, _) = Tabletop::random(config, objects, seed)?;
    Ok(Camera::new(tabletop.grid()).render(&tabletop))
}

/// Wall-clock of one call.
fn timed<T>(f: impl FnOnce() -> T) -> (T, Duration) {
    let start = Instant::now();
    let value = f();
    (value, start.elapsed())
}

fn bench_sim(args: &SimBenchArgs) -> Result<()> {
    let config = SimConfig::default();
    let reps = args.reps.max(1);

    let settle_ms = median(
        (0..reps as u64)
            .map(|seed| ms(timed(|| Tabletop::random(&config, 10, seed)).1))
            .collect(),
    );

    let heightmap_ms = |pixel_size: f32| -> Result<f64> {
        let config = SimConfig::with_pixel_size(pixel_size);
        let (tabletop, _) = Tabletop::random(&config, 10, 0)?;
        let camera = Camera::new(tabletop.grid());
        let mut maps = Heightmaps::new(tabletop.grid());
        Ok(median(
            (0..reps * 10)
                .map(|_| ms(timed(|| camera.render_into(&tabletop, &mut maps)).1))
                .collect(),
        ))
    };
    let heightmap_224_ms = heightmap_ms(0.002)?;
    let heightmap_112_ms = heightmap_ms(0.004)?;

    // Primitives in a 10-object scene, at a pixel on an object, at random rotations.
    let mut push = Vec::new();
    let mut grasp = Vec::new();
    let mut cycle = Vec::new();
    let (mut inside, mut total) = (Duration::ZERO, Duration::ZERO);
    let (mut push_steps, mut grasp_steps) = (Vec::new(), Vec::new());
    for seed in 0..reps as u64 {
        for primitive in [Primitive::Push, Primitive::Grasp] {
            let (mut tabletop, _) = Tabletop::random(&config, 10, seed)?;
            let camera = Camera::new(tabletop.grid());
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let start = Instant::now();
            let before = camera.render(&tabletop);
            let Some((row, col)) = object_pixel(&before, &mut rng) else {
                continue;
            };
            let action = Action {
                primitive,
                rotation: rng.random_range(0..ROTATIONS),
                row,
                col,
            };
            let physics_before = tabletop.physics_time();
            let (outcome, act_time) = timed(|| tabletop.act(&action, &before));
            let outcome = outcome?;
            let _after = camera.render(&tabletop);
            cycle.push(ms(start.elapsed()));
            inside += tabletop.physics_time() - physics_before;
            total += act_time;
            match primitive {
                Primitive::Push => {
                    push.push(ms(act_time));
                    push_steps.push(outcome.physics_steps as f64);
                }
                Primitive::Grasp => {
                    grasp.push(ms(act_time));
                    grasp_steps.push(outcome.physics_steps as f64);
                }
            }
        }
    }

    let rapier_step_us = {
        let (mut tabletop, _) = Tabletop::random(&config, 10, 0)?;
        median(
            (0..reps * 50)
                .map(|_| timed(|| tabletop.step()).1.as_secs_f64() * 1e6)
                .collect(),
        )
    };

    let (isolated_successes, isolated_cube_grasps) = isolated_cube_grasps(&config, args.trials)?;
    let (clutter_successes, clutter_grasps) = clutter_cube_grasps(&config, args.trials)?;
    let empty_successes = empty_table_grasps(&config, args.trials.min(10))?;
    let push_displacement_m = push_displacements(&config, args.trials)?;

    let figures = SimFigures {
        settle_ms,
        heightmap_224_ms,
        heightmap_112_ms,
        push_ms: median(push),
        grasp_ms: median(grasp),
        action_cycle_ms: median(cycle),
        rapier_step_us,
        primitive_outside_step_share: 1.0 - inside.as_secs_f64() / total.as_secs_f64(),
        physics_steps_per_push: median(push_steps),
        physics_steps_per_grasp: median(grasp_steps),
        isolated_cube_grasp_success: isolated_successes as f64 / isolated_cube_grasps as f64,
        isolated_cube_grasps,
        clutter_grasp_success: clutter_successes as f64 / clutter_grasps.max(1) as f64,
        clutter_grasps,
        empty_table_grasp_success: empty_successes as f64 / args.trials.min(10) as f64,
        push_displacement_m,
    };
    print_figures(&serde_json::to_value(&figures)?, args.json)
}

/// One flat JSON object on one line, or a name/value table.
fn print_figures(figures: &serde_json::Value, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(figures)?);
    } else {
        for (name, v) in figures.as_object().into_iter().flatten() {
            println!("{name:32} {v}");
        }
    }
    Ok(())
}

fn bench_learner(args: &LearnerBenchArgs) -> Result<()> {
    use learner::{LearningConfig, Sample, TrainedNet, Trainer};
    use qnet::{ActingNets, Device, Difference, NetInput, QNetConfig, QNets, RotatedQMaps};

    let reps = args.reps.max(1);
    let backend = args.backend;
    let open = rundir::backend::open(backend, "learner")?;
    let device = open.device;
    let net = match &args.config {
        Some(path) => rundir::config::RunConfig::load(path)?.net,
        None => QNetConfig::default(),
    };
    let mut figures = serde_json::Map::new();
    figures.insert("backend".into(), backend.name().into());
    if let Some(adapter) = &open.adapter {
        figures.insert("adapter".into(), adapter.name.clone().into());
        figures.insert("adapter_driver".into(), adapter.driver.clone().into());
        figures.insert("adapter_api".into(), adapter.api.clone().into());
    }
    figures.insert(
        "trunk_widths".into(),
        serde_json::to_value(&net.trunk_widths)?,
    );
    figures.insert(
        "context_dilations".into(),
        serde_json::to_value(&net.context_dilations)?,
    );
    figures.insert("fuse_context".into(), net.fuse_context.into());
    figures.insert(
        "rotation_equivariant".into(),
        net.rotation_equivariant.into(),
    );
    let python = args.python.clone().unwrap_or_else(python::default_python);
    let (mut peer_figures, mut peer_missing) = (serde_json::Map::new(), None);
    let (mut torch_version, mut torch_missing) = (None, None);
    for &side in &args.sides {
        let config = SimConfig::with_pixel_size(sim::workspace::SIDE / side as f32);
        let (tabletop, _) = Tabletop::random(&config, 10, 0)?;
        let maps = Camera::new(tabletop.grid()).render(&tabletop);
        let side = maps.side();
        let goal = maps.visible_ids()[0];
        let input = NetInput::encode(&maps, goal);
        let mut trainer = Trainer::new(
            QNets::new(&net, &device),
            &net,
            side,
            &LearningConfig::default(),
            TrainedNet::Grasp,
            &device,
        );
        let nets = trainer.published_nets();
        let geometry = trainer.geometry().clone();
        let acting = ActingNets::new(&nets)?;
        // The passes over rotated inputs that the 16 rotations take.
        let passes = ROTATIONS as usize / net.group();
        let both = |run: &dyn Fn(Primitive)| {
            median(
                (0..reps)
                    .map(|_| ms(timed(|| [Primitive::Push, Primitive::Grasp].map(run)).1))
                    .collect(),
            )
        };
        // What the actors run (both nets on each rotated input), and burn's own forward of
        // the same nets beside it (on a GPU the actors run burn's forward: timed once).
        let infer = median(
            (0..reps)
                .map(|_| {
                    let primitives = [Primitive::Push, Primitive::Grasp];
                    let run = || acting.all_rotations_of_each(primitives, &[&input], &geometry);
                    ms(timed(|| run().expect("inference")).1)
                })
                .collect(),
        );
        let burn_infer = match &acting {
            ActingNets::Cpu(_) => both(&|primitive| {
                nets.all_rotations(primitive, &input, &geometry)
                    .expect("inference");
            }),
            ActingNets::Device(_) => infer,
        };
        let suffix = format!("_{side}");
        let mut put = |name: &str, value: f64| {
            figures.insert(format!("{name}{suffix}"), value.into());
        };
        put("infer_16rot_ms", infer);
        put("burn_infer_16rot_ms", burn_infer);
        // Each pass's input rotated beforehand: what the peers run.
        let [mut colour, mut depth, mut mask] = [Vec::new(), Vec::new(), Vec::new()];
        for k in 0..passes as u8 {
            geometry.rotate_input(&input, k, [&mut colour, &mut depth, &mut mask]);
        }
        let rotated = [colour.as_slice(), &depth, &mask];
        if let ActingNets::Cpu(inference) = &acting {
            // The convolutions alone: what onnxruntime runs.
            let convs = both(&|primitive| {
                inference.low_maps(primitive, rotated, &geometry);
            });
            put("infer_convs_ms", convs);
            put("infer_rotations_ms", infer - convs);
            if !args.no_peer {
                let ours = [Primitive::Push, Primitive::Grasp]
                    .map(|primitive| inference.low_maps(primitive, rotated, &geometry));
                let run = peer::PeerRun {
                    nets: &nets,
                    rotated,
                    n: passes,
                    padded: geometry.padded(),
                    ours: [&ours[0], &ours[1]],
                    reps,
                    threads: rayon::current_num_threads(),
                };
                match peer::onnxruntime_figures(&python, &run) {
                    Ok(peer) => {
                        let ort = peer["ort_infer_ms"].as_f64().unwrap_or(f64::NAN);
                        put("ort_infer_16rot_ms", ort);
                        put("infer_vs_ort", infer / ort);
                        put(
                            "ort_max_rel_diff",
                            peer["ort_max_rel_diff"].as_f64().unwrap_or(f64::NAN),
                        );
                        peer_figures.extend(peer);
                    }
                    Err(why) => peer_missing = Some(format!("{why:#}")),
                }
            }
        }
        let sample = |k: usize| Sample {
            input: input.clone(),
            action: Action {
                primitive: Primitive::Grasp,
                rotation: (k % 16) as u8,
                row: side / 2,
                col: side / 2 + k,
            },
            label: 1.0,
            weight: 1.0,
            succeeded: true,
        };
        let samples = |batch: usize| (0..batch).map(sample).collect::<Vec<_>>();
        let (train, _) = train_step_ms(&mut trainer, &samples(1), reps)?;
        // The default learning config keeps no average: the published nets are the trained.
        let before_batch = trainer.published_nets();
        let threads_before = thread_cpu::ThreadCpu::now();
        let (batch_train, first_batch) = train_step_ms(&mut trainer, &samples(8), reps)?;
        let threads = thread_cpu::ThreadCpu::now().zip(threads_before);
        let publish = publish_ms(&trainer, reps)?;
        if backend != Backend::Cpu {
            // The same weights on the CPU: how far this device's Q maps are from the CPU's,
            // and the CPU's training step beside this device's.
            let cpu = Device::flex();
            let cpu_nets = QNets::new(&net, &cpu).load_bytes(&nets.to_bytes()?)?;
            let cpu_acting = ActingNets::new(&cpu_nets)?;
            let mut worst = 0f32;
            for primitive in [Primitive::Push, Primitive::Grasp] {
                let here = acting.all_rotations(primitive, &input, &geometry)?;
                let there = cpu_acting.all_rotations(primitive, &input, &geometry)?;
                let difference = Difference::between(here.values(), there.values());
                worst = qnet::agreement::worst(worst, difference.max_rel);
            }
            put("max_rel_diff_vs_cpu", f64::from(worst));
            let learning = LearningConfig::default();
            let mut cpu_trainer =
                Trainer::new(cpu_nets, &net, side, &learning, TrainedNet::Grasp, &cpu);
            let (cpu_batch_train, _) = train_step_ms(&mut cpu_trainer, &samples(8), reps)?;
            put("cpu_batch_train_step_ms", cpu_batch_train);
            put("cpu_publish_ms", publish_ms(&cpu_trainer, reps)?);
            put("batch_train_speedup_vs_cpu", cpu_batch_train / batch_train);
            // Where the host's time went in those steps (the untimed one before them too).
            if let Some((after, before)) = threads {
                let used = after.since(before);
                let per_step_ms = |s: f64| s * 1e3 / (reps + 1) as f64;
                put("batch_train_fusion_cpu_ms", per_step_ms(used.fusion_s));
                put("batch_train_server_cpu_ms", per_step_ms(used.server_s));
                put("batch_train_other_cpu_ms", per_step_ms(used.other_s));
            }
        }
        let per_pass = net.flops_per_pass(geometry.padded());
        let gflop_inference = 2.0 * passes as f64 * per_pass / 1e9;
        // A grasp trains its rotation and the symmetric one, one pass or two (an equivariant
        // net's pass scores angles a quarter turn apart); backward costs about twice the
        // forward.
        let [first, symmetric] =
            [0, ROTATIONS / 2].map(|k| qnet::equivariant::pass_and_channel(k, net.group()).0);
        let passes_per_grasp = if first == symmetric { 1.0 } else { 2.0 };
        let gflop_batch_train = 3.0 * 8.0 * passes_per_grasp * per_pass / 1e9;
        put("train_step_ms", train);
        put("batch_train_step_ms", batch_train);
        put("publish_ms", publish);
        put("gflop_per_inference", gflop_inference);
        put("achieved_gflops", gflop_batch_train / (batch_train / 1e3));
        put("inference_gflops", gflop_inference / (infer / 1e3));
        // PyTorch's training step of the same net beside ours, on the CPU.
        if backend == Backend::Cpu && !args.no_peer {
            let (learning, batch) = (LearningConfig::default(), samples(8));
            let run = peer::TrainingPeerRun {
                net: &before_batch.grasp,
                rotated,
                geometry: &geometry,
                samples: &batch,
                learning: &learning,
                ours: &first_batch,
                reps,
                threads: rayon::current_num_threads(),
            };
            match peer::torch_figures(&python, &run) {
                Ok(peer) => {
                    let figure = |key: &str| peer[key].as_f64().unwrap_or(f64::NAN);
                    let torch_batch = figure("torch_batch_train_step_ms");
                    put("torch_train_step_ms", figure("torch_train_step_ms"));
                    put("torch_batch_train_step_ms", torch_batch);
                    put("batch_train_vs_torch", batch_train / torch_batch);
                    put(
                        "torch_achieved_gflops",
                        gflop_batch_train / (torch_batch / 1e3),
                    );
                    put("torch_max_rel_diff", figure("torch_max_rel_diff"));
                    torch_version = peer.get("torch_version").cloned();
                }
                Err(why) => torch_missing = Some(format!("{why:#}")),
            }
        }
    }
    figures.insert(
        "matmul_peak_gflops".into(),
        matmul_peak_gflops(&device, reps).into(),
    );
    match peer_missing {
        None if args.no_peer => {
            figures.insert("onnxruntime".into(), "not run (--no-peer)".into());
        }
        None => {
            for key in ["sgemm_peak_gflops", "ort_version", "numpy_version"] {
                if let Some(value) = peer_figures.remove(key) {
                    figures.insert(key.into(), value);
                }
            }
        }
        Some(why) => {
            eprintln!(
                "onnxruntime was not run ({why}); to run it beside ours:\n  \
                 python3 -m venv target/bench-venv && \
                 target/bench-venv/bin/python3 -m pip install onnxruntime onnx numpy"
            );
            figures.insert("onnxruntime".into(), format!("not run: {why}").into());
        }
    }
    if let Some(version) = torch_version {
        figures.insert("torch_version".into(), version);
    }
    if let Some(why) = torch_missing {
        eprintln!(
            "PyTorch's training step was not run ({why}); to run it beside ours (about 5 GB \
             with its CUDA libraries):\n  target/bench-venv/bin/python3 -m pip install torch"
        );
        figures.insert("torch".into(), format!("not run: {why}").into());
    }
    print_figures(&serde_json::Value::Object(figures), args.json)
}

/// The median time of `reps` training steps on `samples`, and the report of the untimed
/// step before them.
fn train_step_ms(
    trainer: &mut learner::Trainer,
    samples: &[learner::Sample],
    reps: usize,
) -> Result<(f64, learner::StepReport)> {
    let first = trainer.train_step(samples)?;
    let times = (0..reps)
        .map(|_| timed(|| trainer.train_step(samples)).1)
        .map(ms)
        .collect();
    Ok((median(times), first))
}

/// The median time of `reps` publications of the trainer's nets as bytes: what the learner
/// sends the actors after every update at `publish_every = 1`. An untimed one first: on a
/// GPU it waits for the work still queued (the last step's backward pass), which is the
/// step's, not the publication's.
fn publish_ms(trainer: &learner::Trainer, reps: usize) -> Result<f64> {
    trainer.published_nets().to_bytes()?;
    let times = (0..reps)
        .map(|_| {
            let (bytes, time) = timed(|| trainer.published_nets().to_bytes());
            bytes.map(|_| ms(time))
        })
        .collect::<Result<_, _>>()?;
    Ok(median(times))
}

/// The backend's rate on a large square matrix product, the ceiling for the nets.
fn matmul_peak_gflops(device: &burn::tensor::Device, reps: usize) -> f64 {
    use burn::tensor::{Distribution, Tensor};
    let n = 1024;
    let a = Tensor::<2>::random([n, n], Distribution::Default, device);
    let b = Tensor::<2>::random([n, n], Distribution::Default, device);
    // A value read back: a GPU backend only queues the product.
    let run = || a.clone().matmul(b.clone()).sum().into_scalar::<f32>();
    run();
    let best = (0..reps)
        .map(|_| timed(run).1.as_secs_f64())
        .fold(f64::MAX, f64::min);
    2.0 * (n * n * n) as f64 / best / 1e9
}

/// A random pixel on some object, if any is visible.
fn object_pixel(maps: &Heightmaps, rng: &mut ChaCha8Rng) -> Option<(usize, usize)> {
    let on: Vec<usize> = (0..maps.ids.len()).filter(|&i| maps.ids[i] != 0).collect();
    (!on.is_empty()).then(|| {
        let i = on[rng.random_range(0..on.len())];
        (i / maps.side(), i % maps.side())
    })
}

/// Adds cube `id` within 10 cm of the workspace centre with a random yaw, released at
/// height `z`, and settles.
fn add_random_cube(tabletop: &mut Tabletop, id: u8, z: f32, rng: &mut ChaCha8Rng) -> Result<()> {
    let x = sim::workspace::CENTRE[0] + rng.random_range(-0.1..0.1);
    let y = sim::workspace::CENTRE[1] + rng.random_range(-0.1..0.1);
    let yaw = rng.random_range(0.0..std::f32::consts::TAU);
    let pose = Pose::from_parts(Vector::new(x, y, z), Rotation::from_rotation_z(yaw));
    tabletop.add_object(id, ShapeKind::Cube, sim::SLOT_COLOURS[0], pose)?;
    tabletop.settle();
    Ok(())
}

/// A lone cube resting on the table.
fn lone_cube(config: &SimConfig, rng: &mut ChaCha8Rng) -> Result<Tabletop> {
    let mut tabletop = Tabletop::new(config)?;
    add_random_cube(&mut tabletop, 1, 0.025, rng)?;
    Ok(tabletop)
}

/// Grasps object `id` at the centroid of its visible pixels at a random rotation, if at least
/// `min_visible` of its pixels are seen: whether it was the one grasped.
fn grasp_visible(
    tabletop: &mut Tabletop,
    id: u8,
    min_visible: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Option<bool>> {
    let maps = Camera::new(tabletop.grid()).render(tabletop);
    let Some(MaskShape { row, col, .. }) =
        MaskShape::of(&maps, id).filter(|shape| shape.pixels >= min_visible)
    else {
        return Ok(None);
    };
    let action = Action {
        primitive: Primitive::Grasp,
        rotation: rng.random_range(0..ROTATIONS),
        row,
        col,
    };
    Ok(Some(tabletop.act(&action, &maps)?.grasped == Some(id)))
}

/// Grasps at a lone cube's centre at random angles: (successes, trials).
fn isolated_cube_grasps(config: &SimConfig, trials: usize) -> Result<(usize, usize)> {
    let mut successes = 0;
    for seed in 0..trials as u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(1000 + seed);
        let mut tabletop = lone_cube(config, &mut rng)?;
        let grasped = grasp_visible(&mut tabletop, 1, 1, &mut rng)?;
        successes += usize::from(grasped.expect("a lone cube is visible"));
    }
    Ok((successes, trials))
}

/// Grasps at the visible centre of a cube dropped last among 10 objects, at random angles,
/// in scenes where at least 80% of the cube's top is seen: (successes, trials).
fn clutter_cube_grasps(config: &SimConfig, trials: usize) -> Result<(usize, usize)> {
    let (mut successes, mut attempts) = (0, 0);
    let mostly_visible = (0.8 * (0.05 / config.pixel_size).powi(2)) as usize;
    for seed in 2000..2000 + 10 * trials as u64 {
        if attempts == trials {
            break;
        }
        let (mut tabletop, _) = Tabletop::random(config, 9, seed)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        add_random_cube(&mut tabletop, 10, config.drop_height, &mut rng)?;
        if let Some(grasped) = grasp_visible(&mut tabletop, 10, mostly_visible, &mut rng)? {
            attempts += 1;
            successes += usize::from(grasped);
        }
    }
    Ok((successes, attempts))
}

/// Grasps on an empty table, which must all fail: the number that succeeded.
fn empty_table_grasps(config: &SimConfig, trials: usize) -> Result<usize> {
    let mut successes = 0;
    for seed in 0..trials as u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(3000 + seed);
        let mut tabletop = Tabletop::new(config)?;
        let maps = Camera::new(tabletop.grid()).render(&tabletop);
        let side = maps.side();
        let action = Action {
            primitive: Primitive::Grasp,
            rotation: rng.random_range(0..ROTATIONS),
            row: rng.random_range(side / 4..3 * side / 4),
            col: rng.random_range(side / 4..3 * side / 4),
        };
        successes += usize::from(tabletop.act(&action, &maps)?.grasp_succeeded());
    }
    Ok(successes)
}

/// Median displacement of a lone cube pushed through its centre from 5 cm before it.
fn push_displacements(config: &SimConfig, trials: usize) -> Result<f64> {
    let mut displacements = Vec::new();
    for seed in 0..trials as u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(4000 + seed);
        let mut tabletop = lone_cube(config, &mut rng)?;
        let before = tabletop.object(1).expect("cube").pose.translation;
        let maps = Camera::new(tabletop.grid()).render(&tabletop);
        let rotation = rng.random_range(0..ROTATIONS);
        let angle = sim::rotation_angle(rotation);
        let start = before - 0.05 * Vector::new(angle.cos(), angle.sin(), 0.0);
        let Some((row, col)) = tabletop.grid().pixel_of(start.x, start.y) else {
            continue;
        };
        let action = Action {
            primitive: Primitive::Push,
            rotation,
            row,
            col,
        };
        tabletop.act(&action, &maps)?;
        let after = tabletop.object(1).map_or(before, |o| o.pose.translation);
        displacements.push(((after - before).truncate().length()) as f64);
    }
    Ok(median(displacements))
}
