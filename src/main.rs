//! `pushgrasp`: the command-line program. A thin layer over the workspace's crates: each
//! subcommand's arguments and one call into the crate that does it.

use anyhow::Result;
use cap::Cap;
use clap::{Parser, Subcommand};
use mimalloc::MiMalloc;

/// mimalloc, with a count of the bytes it holds for the program (no limit set): each
/// process logs it beside its resident memory (`runtime::memory`), which tells live data
/// that grows from freed memory the allocator keeps.
#[global_allocator]
static ALLOCATOR: Cap<MiMalloc> = Cap::new(MiMalloc, usize::MAX);

/// Every process hands memory it freed back to the kernel (at mimalloc's own pace, the
/// learner later, an actor at once: [`purge_delay_ms`]) and opts out of transparent huge
/// pages (its children inherit that). Kept longer in the processes that run the nets (for
/// good, then a second) on huge pages, each passing peak stayed, in whole 2 MB pages: over
/// 15-minute soaks an actor and the learner grew 6-14% and were still growing
/// (results/memory-and-faults.md, "Memory over a long run: freed memory kept a second").
fn hand_back_freed_memory() {
    // SAFETY: prctl with PR_SET_THP_DISABLE reads no memory, it sets a flag of this process.
    // A refusal (an old kernel) leaves huge pages on: nothing to handle.
    unsafe { libc::prctl(libc::PR_SET_THP_DISABLE, 1, 0, 0, 0) };
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

/// How long the learner keeps memory it freed before mimalloc hands it back: longer than a
/// pause between its training steps, so that one step's freed tensors are the next step's
/// pages. At mimalloc's own pace (a second) its resident memory followed how often it
/// stepped, between 68 and 137 MB within minutes as the host's load changed; a learner
/// idle for longer than this still gives its memory back.
const LEARNER_PURGE_DELAY_MS: std::ffi::c_long = 10_000;

/// mimalloc's `mi_option_purge_delay`, which `libmimalloc-sys` does not name: its place in
/// `mi_option_e` (mimalloc.h, v3).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// How long an actor keeps memory it freed: not at all. Its live bytes stay level (12.5-13.2
/// MB), but at mimalloc's second its arena's resident pages wandered by a few MB between
/// episodes, past 5% over 15-minute soaks; handed back at once, it stays level too, at the
/// same actions per second (results/memory-and-faults.md, "The actors hand back what they free
/// at once").
const ACTOR_PURGE_DELAY_MS: std::ffi::c_long = 0;

/// The purge delay this command's process sets, where it is not mimalloc's own: the learner
/// role, and `bench learner`, which measures the learner's step; the actor role.
fn purge_delay_ms(command: &Command) -> Option<std::ffi::c_long> {
    match command {
        Command::Role(runtime::RoleArgs {
            role: wire::Role::Learner,
            ..
        })
        | Command::Bench(bench::BenchCommand::Learner(_)) => Some(LEARNER_PURGE_DELAY_MS),
        Command::Role(runtime::RoleArgs {
            role: wire::Role::Actor,
            ..
        }) => Some(ACTOR_PURGE_DELAY_MS),
        _ => None,
    }
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    hand_back_freed_memory();
    if let Some(delay) = purge_delay_ms(&cli.command) {
        // SAFETY: sets one of mimalloc's options, which it reads on each purge; any value is
        // valid.
        unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, delay) };
    }
    runtime::memory::count_live_bytes_with(|| ALLOCATOR.allocated());
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

#[cfg(test)]
mod tests {
    use super::*;

    fn purge_delay_of(args: &[&str]) -> Option<std::ffi::c_long> {
        purge_delay_ms(&Cli::parse_from([&["pushgrasp"], args].concat()).command)
    }

    #[test]
    fn the_purge_delay_option_is_mimallocs() {
        // Its default in mimalloc v3, which neither neighbour option has (1 and 0).
        // SAFETY: reads one of mimalloc's options.
        let delay = unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
        assert_eq!(delay, 1000);
    }

    #[test]
    fn the_learner_keeps_its_freed_memory_longer_and_an_actor_not_at_all() {
        let role = |role| {
            let args = ["role", role, "--run-dir", "run", "--shm-namespace", "n"];
            purge_delay_of(&[&args[..], &["--shm-processes", "4"]].concat())
        };
        assert_eq!(role("learner"), Some(LEARNER_PURGE_DELAY_MS));
        assert_eq!(role("actor"), Some(ACTOR_PURGE_DELAY_MS));
        assert_eq!(role("buffer"), None);
        assert_eq!(
            purge_delay_of(&["bench", "learner"]),
            Some(LEARNER_PURGE_DELAY_MS)
        );
        assert_eq!(purge_delay_of(&["bench", "e2e"]), None);
        assert_eq!(purge_delay_of(&["train"]), None);
    }
}
