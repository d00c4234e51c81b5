//! A run's directory, `<logs>/<run id>/`: every file a run writes, named in this one place.
//! The launcher, the roles, sweeps, pipelines and `inspect` find a run's files through it.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

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

    /// Where the hosts that joined the run keep their own files (`hosts/`): each host's
    /// directory is a run directory of its own, written on that host.
    pub fn hosts(&self) -> PathBuf {
        self.path.join("hosts")
    }

    /// The directory of the joined host `host` (`hosts/<host>/`).
    pub fn host(&self, host: &str) -> RunDir {
        RunDir::new(self.hosts().join(host))
    }

    /// The run's secret, which joining hosts present (`run.secret`, its owner's alone).
    pub fn secret(&self) -> PathBuf {
        self.path.join("run.secret")
    }

    /// The places of the hosts that joined (`hosts.json`).
    pub fn hosts_file(&self) -> PathBuf {
        self.path.join("hosts.json")
    }

    /// Whether a run was started here (its resolved config is written first).
    pub fn holds_run(&self) -> bool {
        self.config().exists()
    }

    /// The run's resolved config, which every role reads (`config.toml`).
    pub fn config(&self) -> PathBuf {
        self.path.join("config.toml")
    }

    /// Writes the run's resolved config whole or not at all (a file beside it, renamed over
    /// it): a run killed as it starts leaves no empty config that `--resume` cannot read.
    pub fn write_config(&self, text: &str) -> Result<()> {
        let part = self.path.join("config.toml.part");
        std::fs::write(&part, text).with_context(|| format!("writing {}", part.display()))?;
        std::fs::rename(&part, self.config())
            .with_context(|| format!("writing {}", self.config().display()))
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

    /// The launcher's heartbeat (`launcher.alive`): touched every second while it supervises;
    /// its roles stop by themselves when it grows stale (a hung launcher).
    pub fn launcher_alive(&self) -> PathBuf {
        self.path.join("launcher.alive")
    }

    /// Which process plays which role now (`processes.json`).
    pub fn processes(&self) -> PathBuf {
        self.path.join("processes.json")
    }

    /// The learner's checkpoint (`checkpoint/`; the one before it `checkpoint.prev/`, as
    /// every generation: see [`previous`]).
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

/// The generation before `path` (a snapshot, its counters, a checkpoint), kept so that a
/// damaged newest one is not the end of a run: `<path>.prev`.
pub fn previous(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".prev");
    PathBuf::from(name)
}

/// Before a new generation of `path` is written: the current one (if any) becomes the
/// previous, replacing the one there.
pub fn keep_previous(path: &Path) -> Result<()> {
    if !path.exists() {
        return Ok(());
    }
    let before = previous(path);
    if before.is_dir() {
        std::fs::remove_dir_all(&before)
    } else if before.exists() {
        std::fs::remove_file(&before)
    } else {
        Ok(())
    }
    .with_context(|| format!("removing {}", before.display()))?;
    std::fs::rename(path, &before).with_context(|| format!("keeping {}", path.display()))
}

/// `load(false)`, the newest generation of `newest`; when it is damaged and a previous one
/// exists, `load(true)` and a warning naming the damaged file, for the role to pass on to
/// the launcher. Both failing is an error naming both.
pub fn newest_or_previous<T>(
    newest: &Path,
    load: impl Fn(bool) -> Result<T>,
) -> Result<(T, Option<String>)> {
    let damaged = match load(false) {
        Ok(value) => return Ok((value, None)),
        Err(e) if previous(newest).exists() => e,
        Err(e) => return Err(e),
    };
    let warning = format!(
        "{} is damaged ({damaged:#}); going on from the previous generation, {}",
        newest.display(),
        previous(newest).display()
    );
    eprintln!("warning: {warning}");
    let value = load(true).with_context(|| {
        format!(
            "{} is damaged ({damaged:#}), and so is the previous generation",
            newest.display()
        )
    })?;
    Ok((value, Some(warning)))
}
