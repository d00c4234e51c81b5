//! `pushgrasp bench`: figures for the hot paths, each beside its floor measured in the same
//! run (for the simulator, one bare rapier step).

use std::time::{Duration, Instant};

use anyhow::Result;
use clap::Subcommand;
use runtime::stopwatch::status_mb;
use sim::{Camera, Heightmaps, SimConfig, Tabletop};

mod e2e;
mod gpu;
mod hosts;
mod logging;
mod nets;
mod peer;
mod python;
mod replay;
mod simulator;
mod soak;
mod thread_cpu;
mod transport;

pub use nets::LearnerBenchArgs;
pub use simulator::SimBenchArgs;

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
    /// Every GPU figure in one go, into one JSON file (a wgpu build, on a GPU host): the
    /// learner at the shipped, the stage and the paper-size nets, a real run with each
    /// learner, and CubeCL's task batching varied; each within its share of one budget.
    Gpu(gpu::GpuBenchArgs),
}

pub fn run(command: BenchCommand) -> Result<()> {
    match command {
        BenchCommand::Sim(args) => simulator::bench_sim(&args),
        BenchCommand::Learner(args) => nets::bench_learner(&args),
        BenchCommand::Buffer(args) => replay::bench_buffer(&args),
        BenchCommand::E2e(args) => e2e::bench_e2e(&args),
        BenchCommand::Logging(args) => logging::bench_logging(&args),
        BenchCommand::Transport(args) => transport::bench_transport(&args),
        BenchCommand::Hosts(args) => hosts::bench_hosts(&args),
        BenchCommand::Soak(args) => soak::bench_soak(&args),
        BenchCommand::Gpu(args) => gpu::bench_gpu(&args),
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
