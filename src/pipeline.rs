//! `pushgrasp pipeline`: the paper's three stages in order, each a `pushgrasp train` run in
//! `logs/<pipeline-id>/stage<N>/` whose nets start from the previous stage's checkpoint. A
//! pipeline started again with the same `--id` skips the stages that finished and resumes
//! the one that was cut short.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result, bail};
use clap::Args;
use serde::Deserialize;

use crate::run::config::RunConfig;
use crate::run::launch::Summary;

#[derive(Args)]
pub struct PipelineArgs {
    /// The pipeline file: its stages' configs, in order.
    #[arg(long, default_value = "configs/pipeline.toml")]
    config: PathBuf,
    /// The pipeline's id and directory name under --logs (default: pipeline-<unix time>);
    /// an existing one is continued.
    #[arg(long)]
    id: Option<String>,
    /// Where the pipeline's directory goes.
    #[arg(long, default_value = "logs")]
    logs: PathBuf,
    /// Run each stage's roles as threads instead of processes.
    #[arg(long)]
    threads: bool,
}

/// A pipeline file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PipelineFile {
    stages: Vec<StageEntry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct StageEntry {
    /// The stage's run config, relative to the pipeline file.
    config: PathBuf,
    /// Overrides the config's episode budget.
    episodes: Option<u64>,
}

pub fn run(args: &PipelineArgs) -> Result<()> {
    let text = std::fs::read_to_string(&args.config)
        .with_context(|| format!("reading {}", args.config.display()))?;
    let file: PipelineFile =
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", args.config.display()))?;
    if file.stages.is_empty() {
        bail!("{}: stages: at least one stage", args.config.display());
    }
    let base = args.config.parent().unwrap_or(Path::new("."));
    // Every stage's config is read before the first starts: a typo in stage 3 should not
    // cost the time of stages 1 and 2.
    let stages: Vec<(PathBuf, RunConfig, &StageEntry)> = file
        .stages
        .iter()
        .map(|entry| {
            let path = base.join(&entry.config);
            Ok((path.clone(), RunConfig::load(&path)?, entry))
        })
        .collect::<Result<_>>()?;
    let id = args.id.clone().unwrap_or_else(|| {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        format!("pipeline-{now}")
    });
    let dir = args.logs.join(&id);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let started = std::time::Instant::now();
    let mut previous: Option<PathBuf> = None;
    let mut lines = Vec::new();
    for (path, config, entry) in &stages {
        let run_id = format!("stage{}", config.stage);
        let run_dir = dir.join(&run_id);
        let finished = Summary::read(&run_dir)?.is_some_and(|s| !s.interrupted);
        if finished {
            println!("{run_id}: finished before, skipped");
        } else {
            let mut command = Command::new(std::env::current_exe()?);
            command
                .arg("train")
                .arg("--config")
                .arg(path)
                .arg("--logs")
                .arg(&dir)
                .args(["--run-id", &run_id]);
            if run_dir.join("config.toml").exists() {
                command.arg("--resume");
            } else if let Some(checkpoint) = &previous {
                command.arg("--init-from").arg(checkpoint);
            }
            if let Some(episodes) = entry.episodes {
                command.args(["--episodes", &episodes.to_string()]);
            }
            if args.threads {
                command.arg("--threads");
            }
            println!("{run_id}: {}", path.display());
            let status = command.status().context("starting train")?;
            if !status.success() {
                bail!(
                    "{run_id} ({}) failed ({status}); its logs are in {}; run the pipeline \
                     again with --id {id} to continue",
                    path.display(),
                    run_dir.display()
                );
            }
        }
        let summary = Summary::read(&run_dir)?
            .with_context(|| format!("{}: no summary.json", run_dir.display()))?;
        lines.push(format!(
            "{run_id}: {} episodes, goal grasp success last 30 {}, {:.0} s",
            summary.buffer.episodes,
            summary
                .buffer
                .success_last30
                .map_or("-".into(), |s| format!("{:.0}%", 100.0 * s)),
            summary.wall_s
        ));
        previous = Some(run_dir.join("checkpoint"));
    }
    println!(
        "pipeline {id} done in {:.0} s ({})",
        started.elapsed().as_secs_f64(),
        dir.display()
    );
    for line in lines {
        println!("  {line}");
    }
    if let Some(checkpoint) = previous {
        println!(
            "test it: pushgrasp eval --checkpoint {} --arrangements configs/arrangements --random 30",
            checkpoint.display()
        );
    }
    Ok(())
}
