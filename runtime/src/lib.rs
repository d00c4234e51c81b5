//! `pushgrasp train`: the distributed runtime. A launcher starts the buffer, the learner and
//! N actors, as child processes of this binary talking over iceoryx2 shared memory (the
//! default) or as threads talking over crossbeam channels (`--threads`); the roles' code is
//! the same in both wirings. With `--listen`, actors on other hosts join the run
//! (`pushgrasp join`, [`join`]): each host keeps its own shared memory, and one bridge per
//! host carries what must cross (the `bridge` crate).

pub mod actor;
pub mod backend;
pub mod buffer;
pub mod config;
pub mod hosts;
pub mod join;
pub mod launch;
pub mod learner;
pub mod machine;
pub mod memory;
pub mod pipeline;
pub mod pretrain;
pub mod progress;
pub mod record;
pub mod role;
pub mod run_dir;
pub mod settings;
pub mod signals;
pub mod stopwatch;
pub mod supervisor;
pub mod worker;

use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use serde::Serialize;
use wire::{Control, Inbox, Message, Role};

pub use join::{JoinArgs, join};
pub use launch::{TrainArgs, train};
pub use pretrain::{PretrainArgs, pretrain};
pub use progress::{Progress, Summary};
pub use role::{RoleArgs, RoleId, role_process};
pub use run_dir::RunDir;

/// Goal grasp success is reported over this many most recent attempts (the paper's metric).
pub const SUCCESS_WINDOW: usize = 30;

/// How often the buffer and the learner report progress.
pub const STATUS_EVERY: Duration = Duration::from_millis(250);

/// Whether the process that started this role is gone or hung (then the role stops by
/// itself: no orphan keeps running after its launcher was killed or stopped).
pub struct Lifeline {
    parent: Option<u32>,
    /// The launcher's heartbeat file, and how stale it may grow.
    heartbeat: Option<(PathBuf, Duration)>,
    /// When the heartbeat was last looked at, and whether it was stale.
    looked: Cell<Option<Instant>>,
    stale: Cell<bool>,
}

impl Lifeline {
    /// A role in a child process, watching its parent and the parent's heartbeat file
    /// (stale after `timeout`).
    pub fn child(heartbeat: PathBuf, timeout: Duration) -> Self {
        Self {
            parent: Some(std::os::unix::process::parent_id()),
            heartbeat: Some((heartbeat, timeout)),
            looked: Cell::new(None),
            stale: Cell::new(false),
        }
    }

    /// A role in a thread of the launcher's own process.
    pub fn thread() -> Self {
        Self {
            parent: None,
            heartbeat: None,
            looked: Cell::new(None),
            stale: Cell::new(false),
        }
    }

    /// Whether the role has its process to itself (its CPU time is its own).
    pub fn own_process(&self) -> bool {
        self.parent.is_some()
    }

    pub fn lost(&self) -> bool {
        self.parent
            .is_some_and(|p| std::os::unix::process::parent_id() != p)
            || self.launcher_hung()
    }

    /// Whether the launcher's heartbeat is older than its timeout (looked at once a second).
    fn launcher_hung(&self) -> bool {
        let Some((file, timeout)) = &self.heartbeat else {
            return false;
        };
        if self
            .looked
            .get()
            .is_some_and(|at| at.elapsed() < Duration::from_secs(1))
        {
            return self.stale.get();
        }
        self.looked.set(Some(Instant::now()));
        let age = std::fs::metadata(file)
            .and_then(|m| m.modified())
            .ok()
            .and_then(|at| at.elapsed().ok());
        let stale = age.is_some_and(|age| age > *timeout);
        if stale && !self.stale.get() {
            eprintln!(
                "the launcher has not beaten for {:.0} s ({}): stopping",
                age.unwrap_or_default().as_secs_f64(),
                file.display()
            );
        }
        self.stale.set(stale);
        stale
    }
}

/// Reads the orders waiting; true if one of them stops `role`.
pub fn stop_requested(control: &mut Inbox, role: Role) -> Result<bool> {
    Ok(control
        .drain()?
        .contains(&Message::Control(Control::Stop(role))))
}

/// Writes JSON through a temporary file, so a reader never sees half of it.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_vec_pretty(value)?)
        .with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))
}

/// Reads what [`write_json`] wrote.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_slice(&bytes).with_context(|| format!("reading {}", path.display()))
}

/// The files in `dir` whose names end in `.<extension>`, sorted; none is an error naming the
/// directory.
pub fn files_with_extension(dir: &Path, extension: &str) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == extension))
        .collect();
    files.sort();
    if files.is_empty() {
        anyhow::bail!("{}: no .{extension} files", dir.display());
    }
    Ok(files)
}
