//! A run's directory, `<logs>/<run id>/`: every file a run writes, named in this one place.
//! The launcher, the roles, sweeps, pipelines and `inspect` find a run's files through it.

use std::path::{Path, PathBuf};

/// The directory of one run.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RunDir {
    path: PathBuf,
}

impl RunDir {
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self { path: path.into() }
    }

    /// The run `run_id` under `logs`.
    pub fn in_logs(logs: &Path, run_id: &str) -> Self {
        Self::new(logs.join(run_id))
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether a run was started here (its resolved config is written first).
    pub fn holds_run(&self) -> bool {
        self.config().exists()
    }

    /// The run's resolved config, which every role reads (`config.toml`).
    pub fn config(&self) -> PathBuf {
        self.path.join("config.toml")
    }

    /// What the finished run says about itself (`summary.json`).
    pub fn summary(&self) -> PathBuf {
        self.path.join("summary.json")
    }

    /// Where each role writes its report when it stops (`reports/`).
    pub fn reports(&self) -> PathBuf {
        self.path.join("reports")
    }

    /// The report of the role named `name` (`reports/<name>.json`).
    pub fn report(&self, name: &str) -> PathBuf {
        self.reports().join(format!("{name}.json"))
    }

    /// A role process's standard output and error (`<name>.log`).
    pub fn log(&self, name: &str) -> PathBuf {
        self.path.join(format!("{name}.log"))
    }

    /// A process's MCAP log (`<name>.mcap`; the launcher's is `launcher.mcap`).
    pub fn mcap(&self, name: &str) -> PathBuf {
        self.path.join(format!("{name}.mcap"))
    }

    /// Which process plays which role now (`processes.json`).
    pub fn processes(&self) -> PathBuf {
        self.path.join("processes.json")
    }

    /// The learner's checkpoint (`checkpoint/`).
    pub fn checkpoint(&self) -> PathBuf {
        self.path.join("checkpoint")
    }

    /// The buffer's snapshot of its replay (`buffer.snapshot`).
    pub fn snapshot(&self) -> PathBuf {
        self.path.join("buffer.snapshot")
    }

    /// The buffer's counters, kept beside its snapshot (`buffer-counters.json`).
    pub fn buffer_counters(&self) -> PathBuf {
        self.path.join("buffer-counters.json")
    }

    /// Per episode: whether its goal was grasped, and the success over the last 30
    /// (`curve.csv`).
    pub fn curve(&self) -> PathBuf {
        self.path.join("curve.csv")
    }
}
