//! `pushgrasp`: the command-line program. A thin layer over the workspace's crates: each
//! subcommand's arguments and one call into the crate that does it.

use anyhow::Result;
use clap::{Parser, Subcommand};
use mimalloc::MiMalloc;

#[global_allocator]
static ALLOCATOR: MiMalloc = MiMalloc;

/// mimalloc's `mi_option_purge_delay` (its place in `mi_option_t`, the same in mimalloc 2 and
/// 3; the Rust bindings do not name it).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// How long memory freed in a process that runs the nets stays there before it goes back to
/// the kernel, in milliseconds. The learner frees and allocates the same megabyte tensors on
/// every step: handed back at once (mimalloc's default), each came back as freshly faulted
/// and zeroed huge pages (a third of a training step's time in `perf`). Kept for good, every
/// transient peak stayed: over a 15-minute `bench soak` the actors grew 7-8% and the learner
/// 4.8%, still climbing at the end. A second outlasts a training step and an action many
/// times over, so the memory in use is reused and a passing peak is handed back (the same
/// soak: every process within 2.7%, levelled off; the training step's time unchanged).
const NETS_PURGE_DELAY_MS: std::ffi::c_long = 1000;

/// Keeps freed memory for [`NETS_PURGE_DELAY_MS`], with huge pages as the system gives them:
/// a process started by a launcher inherits the launcher's opt-out (see
/// [`hand_back_freed_memory`]) and lifts it here.
fn keep_freed_memory() {
    // SAFETY: setting an option is a plain store in mimalloc, valid at any time; prctl with
    // PR_SET_THP_DISABLE reads no memory, it sets a flag of this process.
    unsafe {
        libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, NETS_PURGE_DELAY_MS);
        libc::prctl(libc::PR_SET_THP_DISABLE, 0, 0, 0, 0);
    }
}

/// For a process whose heap is many small objects that come and go (the launcher, the
/// buffer, a host's supervisor): freed memory goes back to the kernel (mimalloc's default)
/// and no transparent huge pages, which made a long run's resident memory creep up in whole
/// 2 MB pages while its heap stayed flat (`pushgrasp bench soak`; RESULTS.md). The
/// processes it starts inherit the opt-out; those that run the nets lift it.
fn hand_back_freed_memory() {
    // SAFETY: as in `keep_freed_memory`. A refusal (an old kernel) leaves huge pages on:
    // nothing to handle.
    unsafe { libc::prctl(libc::PR_SET_THP_DISABLE, 1, 0, 0, 0) };
}

/// Whether `command` runs the nets (their tensors are what keeping freed memory is for).
fn runs_the_nets(command: &Command) -> bool {
    match command {
        Command::Role(args) => !matches!(args.role, wire::Role::Buffer),
        Command::Train(_) | Command::Join(_) | Command::Cluster(_) | Command::Sweep(_) => false,
        _ => true,
    }
}

#[derive(Parser)]
#[command(
    name = "pushgrasp",
    version,
    about = "Learning goal-oriented push-grasping in clutter"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build scenes, look at them, convert arrangement files.
    #[command(subcommand)]
    Scene(scene_tools::SceneCommand),
    /// Run a scripted episode on a random scene and write what the robot saw to logs/.
    Episode(scene_tools::EpisodeArgs),
    /// Train: a buffer, a learner and N actors, as processes over shared memory (or threads).
    Train(runtime::TrainArgs),
    /// Run actors on this host for a run that listens on another (`train --listen`).
    Join(runtime::JoinArgs),
    /// One run across the nodes of a Slurm job: writes (and with --submit submits) its script.
    Cluster(sweep::runner::cluster::ClusterArgs),
    /// The three stages in order, each from the previous stage's checkpoint.
    Pipeline(runtime::pipeline::PipelineArgs),
    /// Pretrain the nets' trunks on the simulator's object outlines, for a first stage to
    /// start from.
    Pretrain(runtime::PretrainArgs),
    /// One role of a training run (started by `train`, not by hand).
    #[command(hide = true)]
    Role(runtime::RoleArgs),
    /// Test a checkpoint the paper's way: completion, goal grasp success, motion number.
    Eval(eval::EvalArgs),
    /// Read a run's MCAP logs: files, counts, the goal grasp success curve.
    Inspect(inspect::InspectArgs),
    /// Work on MCAP log files.
    #[command(subcommand)]
    Logs(inspect::LogsCommand),
    /// Measure the hot paths.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Run a sweep file's training runs (locally or as a Slurm job array); their status and
    /// summary.
    Sweep(sweep::runner::SweepArgs),
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    if runs_the_nets(&cli.command) {
        keep_freed_memory();
    } else {
        hand_back_freed_memory();
    }
    match cli.command {
        Command::Scene(command) => scene_tools::run(command),
        Command::Episode(args) => scene_tools::episode(&args),
        Command::Train(args) => runtime::train(&args),
        Command::Join(args) => runtime::join(&args),
        Command::Cluster(args) => sweep::runner::cluster::run(&args),
        Command::Pipeline(args) => runtime::pipeline::run(&args),
        Command::Pretrain(args) => runtime::pretrain(&args),
        Command::Role(args) => runtime::role_process(&args),
        Command::Eval(args) => eval::run(&args),
        Command::Inspect(args) => inspect::inspect(&args),
        Command::Logs(command) => inspect::logs(command),
        Command::Bench(command) => bench::run(command),
        Command::Sweep(args) => sweep::runner::run(&args),
    }
}
