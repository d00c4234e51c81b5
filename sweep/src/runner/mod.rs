//! `pushgrasp sweep`: runs every run of a sweep file (the `sweep` crate expands it) as a
//! `pushgrasp train` of its own, either locally as a bounded pool of child processes or as a
//! Slurm job array, in one sweep directory; `sweep status` says where each run stands and
//! `sweep summary` tabulates the results, with statistics over seeds and the success curves
//! overlaid.
//!
//! This file holds the command line and the start of a sweep; `plan` checks the runs,
//! `dir` owns the sweep directory, `local` and `submit` (Slurm) are the two backends.

pub mod cluster;
mod dir;
mod local;
mod plan;
mod status;
mod submit;
mod summary;
mod table;

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::{Args, Subcommand};

pub use dir::Backend;
use dir::SweepDir;
use plan::Plan;

#[derive(Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct SweepArgs {
    #[command(subcommand)]
    command: Option<SweepCommand>,
    /// The sweep file (e.g. configs/sweeps/stage1-seeds.toml).
    #[arg(long, required = true)]
    config: Option<PathBuf>,
    /// List the runs and check each resolved config; start nothing.
    #[arg(long)]
    dry_run: bool,
    /// With --dry-run: also print each run's resolved config.
    #[arg(long, requires = "dry_run")]
    verbose: bool,
    /// Runs at once (local: default max(1, cores / (actors + 2)); slurm: the array's `%N`
    /// limit, default the sweep file's [slurm] max_parallel).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    max_parallel: Option<u32>,
    /// Continue the sweep in its directory: finished runs are skipped, unfinished ones
    /// continue from their checkpoint, the rest start.
    #[arg(long)]
    resume: bool,
    /// Where the runs run.
    #[arg(long, value_enum, default_value_t = Backend::Local)]
    backend: Backend,
    /// With --backend slurm: write the job script but do not submit it.
    #[arg(long)]
    no_submit: bool,
    /// Where sweep directories go (the sweep's is <logs>/<sweep name>).
    #[arg(long, default_value = "logs")]
    logs: PathBuf,
}

#[derive(Subcommand)]
enum SweepCommand {
    /// Where each run of a sweep stands: done, running, unfinished, not started or failed
    /// (and its Slurm task's state, for a submitted sweep).
    Status {
        /// The sweep directory (<logs>/<sweep name>).
        dir: PathBuf,
    },
    /// One row per run (its axis values, episodes, final success, episodes to 80%,
    /// wall-clock), then the mean and spread over seeds.
    Summary(summary::SummaryArgs),
}

pub fn run(args: &SweepArgs) -> Result<()> {
    match &args.command {
        Some(SweepCommand::Status { dir }) => status::print(&SweepDir::open(dir)?),
        Some(SweepCommand::Summary(summary)) => summary::print(summary),
        None => {
            let Some(config) = &args.config else {
                bail!("give a sweep file with --config, or a subcommand (status, summary)");
            };
            start(args, config)
        }
    }
}

/// Starts (or with --resume continues) the sweep of `config`, or only lists it.
fn start(args: &SweepArgs, config: &Path) -> Result<()> {
    if args.no_submit && args.backend != Backend::Slurm {
        bail!("--no-submit only applies to --backend slurm");
    }
    let plan = Plan::load(config)?;
    if args.dry_run {
        plan.print(args.verbose);
        return Ok(());
    }
    let dir = SweepDir::at(args.logs.join(&plan.sweep.name));
    let state = if args.resume {
        let state = dir.resume(&plan, args.backend)?;
        submit::ensure_idle(&state)?;
        state
    } else {
        dir.create(&plan, args.backend)?
    };
    match args.backend {
        Backend::Local => local::run(&dir, state, &plan, args.max_parallel),
        Backend::Slurm => submit::submit(&dir, state, &plan, args.max_parallel, args.no_submit),
    }
}
