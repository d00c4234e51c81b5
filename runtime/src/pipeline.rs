//! `pushgrasp pipeline`: the paper's three stages in order, each a `pushgrasp train` run in
//! `logs/<pipeline-id>/stage<N>/` whose nets start from the previous stage's checkpoint. A
//! pipeline started again with the same `--id` skips the stages that finished and resumes
//! the one that was cut short.
//!
//! A pipeline file's `[set]` table changes every stage's config the same way: the baselines
//! and ablations in `configs/` are the stage configs with one part of the method switched
//! off. The resolved configs are written beside the stages (`stage<N>.toml`).

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result, bail};
use clap::Args;
use serde::Deserialize;

use rundir::backend::{self, Backend};
use rundir::config::RunConfig;
use rundir::run_dir::RunDir;
use rundir::settings::{load_with, merge, parse_setting};
use rundir::{Summary, percent};

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
    /// A setting for every stage, after the file's `[set]`: a dotted key and a TOML value,
    /// e.g. `--set seed=4` or `--set push_reward='"none"'`. Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = parse_setting)]
    set: Vec<toml::Table>,
    /// The backend of every stage's learner and actors, `cpu` or `wgpu` (before --set).
    #[arg(long)]
    backend: Option<Backend>,
}

/// A pipeline file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PipelineFile {
    stages: Vec<StageEntry>,
    /// Settings that replace the stage configs' own, as a TOML table (nested tables merge).
    #[serde(default)]
    set: toml::Table,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct StageEntry {
    /// The stage's run config, relative to the pipeline file.
    config: PathBuf,
    /// Overrides the config's episode budget.
    episodes: Option<u64>,
    /// Overrides the config's learner-update budget (the run ends at whichever budget comes
    /// first; an episode budget of 0 leaves updates alone to end it).
    updates: Option<u64>,
    /// Settings for this stage alone, under the file's `[set]` and `--set`.
    #[serde(default)]
    set: toml::Table,
    /// Nets trained for the last stage from the same start, each with a seed of its own
    /// ([`member_seed`]); `eval --ensemble` tests them as one.
    #[serde(default = "one")]
    members: u32,
}

fn one() -> u32 {
    1
}

/// Ensemble member `member`'s (1, 2, ...) seed: the first keeps the stage's own; the others
/// lie far from it, so that pipelines started at consecutive seeds share no member's seed.
fn member_seed(seed: u64, member: u32) -> u64 {
    seed.wrapping_add(1000 * u64::from(member - 1))
}

/// Ensemble member `member`'s run id: the first is the stage's own (`stage3`), the others
/// `stage3-member2`, ...
fn member_run_id(stage: u8, member: u32) -> String {
    match member {
        1 => format!("stage{stage}"),
        _ => format!("stage{stage}-member{member}"),
    }
}

/// A stage's config: the file named and, with a `[set]`, the text it resolves to.
struct Stage<'a> {
    path: PathBuf,
    resolved: Option<String>,
    config: RunConfig,
    entry: &'a StageEntry,
}

impl PipelineFile {
    fn load(path: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let file: PipelineFile =
            toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        if file.stages.is_empty() {
            bail!("{}: stages: at least one stage", path.display());
        }
        let last = file.stages.len() - 1;
        for (i, stage) in file.stages.iter().enumerate() {
            if stage.members == 0 || (stage.members > 1 && i != last) {
                bail!(
                    "{}: stages[{i}].members = {}: at least 1, and more only for the last stage \
                     (a stage after it starts from one checkpoint)",
                    path.display(),
                    stage.members
                );
            }
        }
        Ok(file)
    }

    /// Every stage's config, resolved and checked (`path`: where this file is).
    fn stages(&self, path: &Path) -> Result<Vec<Stage<'_>>> {
        let base = path.parent().unwrap_or(Path::new("."));
        self.stages
            .iter()
            .map(|entry| {
                let config_path = base.join(&entry.config);
                let mut set = entry.set.clone();
                merge(&mut set, &self.set);
                let by = format!(
                    "the stage's set, the [set] of {} and any --set",
                    path.display()
                );
                let (config, resolved) = load_with(&config_path, &set, &by)?;
                Ok(Stage {
                    config,
                    path: config_path,
                    resolved,
                    entry,
                })
            })
            .collect()
    }
}

pub fn run(args: &PipelineArgs) -> Result<()> {
    let mut file = PipelineFile::load(&args.config)?;
    if let Some(backend) = args.backend {
        merge(&mut file.set, &backend::setting(backend));
    }
    for setting in &args.set {
        merge(&mut file.set, setting);
    }
    // Every stage's config is resolved and checked before the first starts: a typo in stage
    // 3 should not cost the time of stages 1 and 2.
    let stages = file.stages(&args.config)?;
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
    let mut members = Vec::new();
    let mut lines = Vec::new();
    for stage in &stages {
        // A [set] pipeline trains on its resolved configs, kept beside the stages.
        let path = match &stage.resolved {
            Some(text) => {
                let out = dir.join(format!("stage{}.toml", stage.config.stage));
                std::fs::write(&out, text).with_context(|| format!("writing {}", out.display()))?;
                out
            }
            None => stage.path.clone(),
        };
        members.clear();
        for member in 1..=stage.entry.members {
            let run = StageRun {
                run_id: member_run_id(stage.config.stage, member),
                seed: (member > 1).then(|| member_seed(stage.config.seed, member)),
                config: &path,
                episodes: stage.entry.episodes,
                updates: stage.entry.updates,
                init_from: previous.as_deref(),
            };
            let (checkpoint, line) = run.run(&dir, &id, args.threads)?;
            lines.push(line);
            members.push(checkpoint);
        }
        previous = members.first().cloned();
    }
    println!(
        "pipeline {id} done in {:.0} s ({})",
        started.elapsed().as_secs_f64(),
        dir.display()
    );
    for line in lines {
        println!("  {line}");
    }
    if let Some((first, others)) = members.split_first() {
        let ensemble: String = others
            .iter()
            .map(|c| format!(" --ensemble {}", c.display()))
            .collect();
        println!(
            "test it: pushgrasp eval --checkpoint {}{ensemble} --settings configs/test-time.toml --arrangements configs/arrangements --random 30",
            first.display()
        );
    }
    Ok(())
}

/// One `pushgrasp train` run of a pipeline's stage (one ensemble member).
struct StageRun<'a> {
    run_id: String,
    /// A seed in place of the config's (the ensemble's later members).
    seed: Option<u64>,
    config: &'a Path,
    episodes: Option<u64>,
    updates: Option<u64>,
    /// The previous stage's checkpoint.
    init_from: Option<&'a Path>,
}

impl StageRun<'_> {
    /// Trains it in `dir` (skipped if it finished before, resumed if it was cut short);
    /// its checkpoint and the pipeline's closing line about it.
    fn run(&self, dir: &Path, id: &str, threads: bool) -> Result<(PathBuf, String)> {
        let run_id = &self.run_id;
        let run_dir = RunDir::in_logs(dir, run_id);
        let finished = Summary::read(&run_dir)?.is_some_and(|s| s.finished());
        if finished {
            println!("{run_id}: finished before, skipped");
        } else {
            let mut command = Command::new(std::env::current_exe()?);
            command
                .arg("train")
                .arg("--config")
                .arg(self.config)
                .arg("--logs")
                .arg(dir)
                .args(["--run-id", run_id]);
            if let Some(seed) = self.seed {
                command.args(["--set", &format!("seed={seed}")]);
            }
            if run_dir.holds_run() {
                command.arg("--resume");
            } else if let Some(checkpoint) = self.init_from {
                command.arg("--init-from").arg(checkpoint);
            }
            if let Some(episodes) = self.episodes {
                command.args(["--episodes", &episodes.to_string()]);
            }
            if let Some(updates) = self.updates {
                command.args(["--updates", &updates.to_string()]);
            }
            if threads {
                command.arg("--threads");
            }
            let seed = self.seed.map(|s| format!(", seed {s}")).unwrap_or_default();
            println!("{run_id}: {}{seed}", self.config.display());
            let status = command.status().context("starting train")?;
            if !status.success() {
                bail!(
                    "{run_id} ({}) failed ({status}); its logs are in {}; run the pipeline \
                     again with --id {id} to continue",
                    self.config.display(),
                    run_dir.path().display()
                );
            }
        }
        let summary = Summary::read(&run_dir)?
            .with_context(|| format!("{}: no summary", run_dir.path().display()))?;
        let line = format!(
            "{run_id}: {} episodes, {} updates, goal grasp success last 30 {}, {:.0} s",
            summary.buffer.episodes,
            summary.learner.updates,
            percent(summary.buffer.success_last30),
            summary.wall_s
        );
        Ok((run_dir.checkpoint(), line))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_pipelines_resolve_to_valid_stage_configs() {
        let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        let mut files = rundir::files_with_extension(&configs.join("ablations"), "toml").unwrap();
        files.extend(
            rundir::files_with_extension(&configs, "toml")
                .unwrap()
                .into_iter()
                .filter(|f| {
                    f.file_name()
                        .is_some_and(|n| n.to_string_lossy().starts_with("pipeline"))
                }),
        );
        assert!(files.len() >= 6, "{files:?}");
        for path in files {
            let file = PipelineFile::load(&path).unwrap();
            let stages = file.stages(&path).unwrap();
            assert!(!stages.is_empty(), "{}", path.display());
            for stage in &stages {
                assert_eq!(
                    stage.resolved.is_some(),
                    !(file.set.is_empty() && stage.entry.set.is_empty()),
                    "{}",
                    path.display()
                );
            }
        }
    }

    #[test]
    fn a_stages_own_set_applies_to_it_alone_and_yields_to_the_files() {
        let dir = tempfile::tempdir().unwrap();
        for stage in ["stage1.toml", "stage2.toml"] {
            let from = Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../configs")
                .join(stage);
            std::fs::copy(from, dir.path().join(stage)).unwrap();
        }
        let path = dir.path().join("pipeline.toml");
        let write = |text: &str| std::fs::write(&path, text).unwrap();
        write(
            "[set]\nseed = 7\n[[stages]]\nconfig = \"stage1.toml\"\nset = { grasp_trials = 3, seed = 9 }\n\
             [[stages]]\nconfig = \"stage2.toml\"\n",
        );
        let file = PipelineFile::load(&path).unwrap();
        let stages = file.stages(&path).unwrap();
        let (one, two) = (&stages[0].config, &stages[1].config);
        assert_eq!((one.grasp_trials, one.seed), (3, 7));
        assert_eq!((two.grasp_trials, two.seed), (0, 7));
        // Several nets only for the last stage: a later one starts from one checkpoint.
        write(
            "[[stages]]\nconfig = \"stage1.toml\"\nmembers = 2\n\
             [[stages]]\nconfig = \"stage2.toml\"\n",
        );
        let err = PipelineFile::load(&path).err().unwrap().to_string();
        assert!(err.contains("stages[0].members = 2"), "{err}");
        write("[[stages]]\nconfig = \"stage2.toml\"\nmembers = 0\n");
        let err = PipelineFile::load(&path).err().unwrap().to_string();
        assert!(err.contains("stages[0].members = 0"), "{err}");
        // Stage 2 freezes the grasp net: trials there are refused, naming the stage's file.
        write("[[stages]]\nconfig = \"stage2.toml\"\nset = { grasp_trials = 3 }\n");
        let file = PipelineFile::load(&path).unwrap();
        let err = file.stages(&path).err().unwrap().to_string();
        assert!(
            err.contains("stage2.toml") && err.contains("grasp_trials"),
            "{err}"
        );
    }
}
