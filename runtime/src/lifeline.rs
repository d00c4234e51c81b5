//! When a role stops by itself: its launcher's process gone or hung ([`Lifeline`]), or an
//! order to stop among its control messages; and how often the buffer and the learner report.

use std::cell::Cell;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Result;
use wire::{Control, Inbox, Message, Role};

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
