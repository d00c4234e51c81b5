//! The sweep directory, `<logs>/<sweep name>/`, and what it says about each run:
//!
//! - `sweep.toml`: a copy of the sweep file; `sweep.json`: the state (the runs and their
//!   overrides, the backend, the Slurm job array);
//! - `runs/<run-id>.toml`: each run's resolved config, what `train --config` reads;
//! - `<run-id>/`: each run's own run directory (`train --logs <sweep dir> --run-id <run-id>`,
//!   so each run also has its own shared-memory namespace);
//! - `output/<run-id>.log`: a local run's stdout and stderr; `slurm/<job>_<task>.out`: a
//!   Slurm task's; `sweep.sbatch`: the Slurm job script.

use std::fmt;
use std::path::{Path, PathBuf};

use crate::RunPlan;
use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use serde::{Deserialize, Serialize};

use super::plan::Plan;
use rundir::ProcessEntry;
use rundir::record::LAUNCHER_PROGRESS;
use rundir::{Progress, RunDir, Summary};
use rundir::{read_json, write_json};

/// Where a sweep's runs run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// Child processes of this program on this machine.
    Local,
    /// A Slurm job array, one task per run.
    Slurm,
}

impl std::fmt::Display for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(match self {
            Backend::Local => "local",
            Backend::Slurm => "slurm",
        })
    }
}

/// `sweep.json`.
#[derive(Debug, Serialize, Deserialize)]
pub struct SweepState {
    pub name: String,
    /// The sweep file as given when the sweep started (`sweep.toml` is its copy).
    pub sweep_file: PathBuf,
    /// The backend of the latest start.
    pub backend: Backend,
    pub runs: Vec<RunEntry>,
    /// The latest job array submitted, if any.
    #[serde(default)]
    pub slurm: Option<SlurmJob>,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct RunEntry {
    pub id: String,
    /// The dotted keys this run sets, in axis order.
    pub overrides: Vec<(String, toml::Value)>,
    /// Why the run's latest local start failed; cleared when it starts again.
    #[serde(default)]
    pub failure: Option<String>,
}

/// A submitted job array: its id and the run of each array index.
#[derive(Debug, Serialize, Deserialize)]
pub struct SlurmJob {
    pub job_id: String,
    pub runs: Vec<String>,
}

/// Where a run stands, read from the sweep directory.
#[derive(Debug, Clone, PartialEq)]
pub enum RunState {
    NotStarted,
    /// Its roles' processes are alive on this machine.
    Running,
    /// Started, but neither finished nor running: interrupted, or killed.
    Unfinished,
    Done,
    Failed(String),
}

impl RunState {
    /// The state without its details.
    pub fn kind(&self) -> &'static str {
        match self {
            RunState::NotStarted => "not started",
            RunState::Running => "running",
            RunState::Unfinished => "unfinished",
            RunState::Done => "done",
            RunState::Failed(_) => "failed",
        }
    }
}

impl fmt::Display for RunState {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match self {
            RunState::Failed(why) => write!(f, "failed ({why})"),
            other => f.write_str(other.kind()),
        }
    }
}

pub struct SweepDir {
    path: PathBuf,
}

impl SweepDir {
    pub fn at(path: PathBuf) -> Self {
        Self { path }
    }

    /// An existing sweep directory.
    pub fn open(path: &Path) -> Result<Self> {
        let dir = Self::at(path.to_path_buf());
        if !dir.state_file().exists() {
            bail!(
                "{} is not a sweep directory (it has no sweep.json)",
                path.display()
            );
        }
        Ok(dir)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn state_file(&self) -> PathBuf {
        self.path.join("sweep.json")
    }

    pub fn run_config(&self, id: &str) -> PathBuf {
        self.path.join("runs").join(format!("{id}.toml"))
    }

    pub fn run_dir(&self, id: &str) -> RunDir {
        RunDir::in_logs(&self.path, id)
    }

    pub fn output(&self, id: &str) -> PathBuf {
        self.path.join("output").join(format!("{id}.log"))
    }

    pub fn script(&self) -> PathBuf {
        self.path.join("sweep.sbatch")
    }

    /// The command that continues this sweep (`--backend` and other options to add).
    pub fn resume_command(&self, state: &SweepState) -> String {
        format!(
            "pushgrasp sweep --config {} --logs {} --resume",
            state.sweep_file.display(),
            self.path.parent().unwrap_or(Path::new(".")).display()
        )
    }

    pub fn read_state(&self) -> Result<SweepState> {
        read_json(&self.state_file())
    }

    pub fn write_state(&self, state: &SweepState) -> Result<()> {
        write_json(&self.state_file(), state)
    }

    /// Makes the directory of a new sweep: the sweep file's copy, every run's config, the
    /// state. An existing directory is an error (a sweep is continued with --resume).
    pub fn create(&self, plan: &Plan, backend: Backend) -> Result<SweepState> {
        if let Some(parent) = self.path.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
        }
        // create_dir, not create_dir_all: of two sweeps started at once, one gets the error.
        match std::fs::create_dir(&self.path) {
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => bail!(
                "{} already exists: continue that sweep with --resume, or remove it to start \
                 afresh",
                self.path.display()
            ),
            result => result.with_context(|| format!("creating {}", self.path.display()))?,
        }
        for sub in ["runs", "output"] {
            std::fs::create_dir(self.path.join(sub))?;
        }
        let copy = self.path.join("sweep.toml");
        std::fs::copy(&plan.sweep.path, &copy).with_context(|| {
            format!(
                "copying {} to {}",
                plan.sweep.path.display(),
                copy.display()
            )
        })?;
        for (run, _) in &plan.runs {
            let path = self.run_config(&run.id);
            std::fs::write(&path, run.config_toml())
                .with_context(|| format!("writing {}", path.display()))?;
        }
        let state = SweepState {
            name: plan.sweep.name.clone(),
            sweep_file: plan.sweep.path.clone(),
            backend,
            runs: plan
                .runs
                .iter()
                .map(|(run, _)| RunEntry {
                    id: run.id.clone(),
                    overrides: run.overrides.clone(),
                    failure: None,
                })
                .collect(),
            slurm: None,
        };
        self.write_state(&state)?;
        Ok(state)
    }

    /// The state of an existing sweep to continue, checked against the sweep file as it is
    /// now: the same runs with the same configs, and none of them still running here.
    pub fn resume(&self, plan: &Plan, backend: Backend) -> Result<SweepState> {
        if !self.state_file().exists() {
            bail!(
                "--resume: there is no sweep in {} (no sweep.json); start it without --resume",
                self.path.display()
            );
        }
        let mut state = self.read_state()?;
        let changed = |what: String| {
            anyhow::anyhow!(
                "--resume: {what}: {} or its base config changed since the sweep in {} \
                 started; restore them, or start a new sweep under another name",
                plan.sweep.path.display(),
                self.path.display()
            )
        };
        let ids: Vec<&str> = plan.runs.iter().map(|(run, _)| run.id.as_str()).collect();
        let had: Vec<&str> = state.runs.iter().map(|run| run.id.as_str()).collect();
        if ids != had {
            return Err(changed(format!(
                "the sweep file now gives runs {ids:?}, not {had:?}"
            )));
        }
        for (run, _) in &plan.runs {
            let path = self.run_config(&run.id);
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            let written: toml::Table =
                toml::from_str(&text).with_context(|| format!("reading {}", path.display()))?;
            if written != run.config {
                return Err(changed(format!(
                    "run {}'s config is no longer {}",
                    run.id,
                    path.display()
                )));
            }
            // E.g. the orphan of a sweep that was killed alone: a second launcher on the same
            // run directory would fight it.
            if self.roles_alive(&run.id) {
                bail!(
                    "--resume: run {} is still running (its processes are alive); wait for \
                     it or stop it first",
                    run.id
                );
            }
        }
        state.backend = backend;
        self.write_state(&state)?;
        Ok(state)
    }

    /// Each run as the `sweep` crate plans it, its config read back from `runs/`.
    pub fn plans(&self, state: &SweepState) -> Result<Vec<RunPlan>> {
        state
            .runs
            .iter()
            .enumerate()
            .map(|(index, entry)| {
                let path = self.run_config(&entry.id);
                let text = std::fs::read_to_string(&path)
                    .with_context(|| format!("reading {}", path.display()))?;
                Ok(RunPlan {
                    index,
                    id: entry.id.clone(),
                    overrides: entry.overrides.clone(),
                    config: toml::from_str(&text)
                        .with_context(|| format!("reading {}", path.display()))?,
                })
            })
            .collect()
    }

    /// The run's `summary.json`, if it wrote one.
    pub fn summary(&self, id: &str) -> Result<Option<Summary>> {
        Summary::read(&self.run_dir(id))
    }

    /// Whether the run ended by itself at its budget ([`Summary::finished`]): `--resume`
    /// leaves it alone, even one that lost steps, whose budget is spent; a run that was
    /// interrupted or that a fault ended continues from its checkpoint.
    pub fn finished(&self, id: &str) -> Result<bool> {
        Ok(self.summary(id)?.is_some_and(|s| s.finished()))
    }

    /// Whether the run has a config in its run directory (`train` has taken it on).
    pub fn started(&self, id: &str) -> bool {
        self.run_dir(id).holds_run()
    }

    /// Where the run stands, from its directory alone (a Slurm task's state is not in it).
    pub fn run_state(&self, entry: &RunEntry) -> Result<RunState> {
        if self.roles_alive(&entry.id) {
            return Ok(RunState::Running);
        }
        // A failure belongs to the latest start; a summary may be older (a resumed run).
        if let Some(why) = &entry.failure {
            return Ok(RunState::Failed(why.clone()));
        }
        Ok(match self.summary(&entry.id)? {
            Some(summary) if summary.interrupted => RunState::Unfinished,
            Some(Summary {
                failure: Some(why), ..
            }) => RunState::Failed(why),
            Some(summary) if summary.buffer.lost() > 0 => {
                RunState::Failed(format!("{} steps lost", summary.buffer.lost()))
            }
            Some(_) => RunState::Done,
            None if self.started(&entry.id) => RunState::Unfinished,
            None => RunState::NotStarted,
        })
    }

    /// Whether any role process the run's `processes.json` names is alive on this machine:
    /// its command line still carries the run's id (a zombie's or a reused pid's does not).
    pub fn roles_alive(&self, id: &str) -> bool {
        let path = self.run_dir(id).processes();
        let Ok(entries) = read_json::<Vec<ProcessEntry>>(&path) else {
            return false;
        };
        entries.iter().any(|entry| {
            std::fs::read(format!("/proc/{}/cmdline", entry.pid))
                .is_ok_and(|cmdline| cmdline.split(|&b| b == 0).any(|arg| arg == id.as_bytes()))
        })
    }

    /// The episodes a running run has finished, from its launcher's newest progress record
    /// (`curve.csv` is only written at snapshots). `None` without an MCAP log.
    pub fn live_episodes(&self, id: &str) -> Option<u64> {
        let log = self.run_dir(id).mcap("launcher");
        let last = mcaplog::newest_json_message(&log, LAUNCHER_PROGRESS).ok()??;
        serde_json::from_value::<Progress>(last)
            .ok()
            .map(|progress| progress.episodes)
    }
}
