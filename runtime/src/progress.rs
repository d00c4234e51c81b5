//! What the launcher knows of a run while it goes ([`Progress`], from every role's status
//! reports), how it shows it ([`Display`]), and what it says of the run at the end
//! ([`Summary`](rundir::summary::Summary)).

use std::collections::{BTreeMap, HashSet};
use std::io::IsTerminal;
use std::time::{Duration, Instant};

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use mcaplog::LogLevel;
use wire::{Inbox, Message, Role, Status};

use crate::actor::ActorId;
use crate::memory::MemorySampler;
use crate::role::RoleId;
use crate::supervisor::Supervisor;
use rundir::record::LAUNCHER_PROGRESS;
use rundir::{ActorProgress, Progress};

/// Takes a status report into `progress`; a failure report is returned as text.
pub fn take(progress: &mut Progress, status: Status) -> Option<String> {
    match status {
        Status::Buffer {
            steps_received,
            episodes,
            success_last30,
            stored,
            capacity,
            relabelled,
            lost,
            ..
        } => {
            progress.steps_received = steps_received;
            progress.episodes = episodes;
            progress.success_last30 = success_last30;
            progress.stored = stored;
            progress.capacity = capacity;
            progress.relabelled = relabelled;
            progress.lost = lost;
        }
        Status::Learner {
            updates,
            weights_version,
            loss,
        } => {
            progress.updates = updates;
            progress.weights_version = weights_version;
            progress.loss = loss;
        }
        Status::Actor {
            actor,
            incarnation,
            episodes,
            steps_sent,
            weights_version,
        } => {
            let actor_progress = ActorProgress {
                incarnation,
                episodes,
                steps_sent,
                weights_version,
            };
            progress.actors.insert(actor, actor_progress);
        }
        Status::Failed { role, error } => return Some(format!("{role}: {error}")),
        Status::Tuning { .. } | Status::Warning { .. } => {}
    }
    None
}

/// The progress a person sees: a bar on a terminal, else a line every 10 s; and the
/// launcher's log of it every second, with the launcher process's memory.
pub struct Display {
    bar: Option<ProgressBar>,
    episodes: u64,
    start: Instant,
    last_print: Instant,
    last_logged: Instant,
    /// Updates counted at `rate_at`, for the rate over the last two seconds.
    rate_updates: u64,
    rate_at: Instant,
    updates_per_s: f64,
    memory: MemorySampler,
}

impl Display {
    pub fn new(episodes: u64, start: Instant) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = ProgressBar::new(episodes);
            bar.set_style(
                ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:30}] {pos}/{len} episodes | {msg}",
                )
                .expect("a valid template")
                .progress_chars("=> "),
            );
            bar
        });
        let now = Instant::now();
        Self {
            bar,
            episodes,
            start,
            last_print: now,
            last_logged: now,
            rate_updates: 0,
            rate_at: now,
            updates_per_s: 0.0,
            memory: MemorySampler::default(),
        }
    }

    pub fn show(&mut self, progress: &Progress, supervisor: &Supervisor) -> Result<()> {
        if self.rate_at.elapsed() >= Duration::from_secs(2) {
            let done = progress.updates - self.rate_updates.min(progress.updates);
            self.updates_per_s = done as f64 / self.rate_at.elapsed().as_secs_f64();
            self.rate_updates = progress.updates;
            self.rate_at = Instant::now();
        }
        if self.last_logged.elapsed() >= Duration::from_secs(1) {
            supervisor.log.json(LAUNCHER_PROGRESS, progress)?;
            self.last_logged = Instant::now();
        }
        self.memory.log_if_due(&supervisor.log)?;
        let line = progress.line(self.updates_per_s);
        match &self.bar {
            Some(bar) => {
                bar.set_position(progress.episodes);
                bar.set_message(format!("{line} | restarts {}", supervisor.restarts()));
            }
            None if self.last_print.elapsed() >= Duration::from_secs(10) => {
                println!(
                    "{:7.1} s  episodes {}/{}  {line}",
                    self.start.elapsed().as_secs_f64(),
                    progress.episodes,
                    self.episodes
                );
                self.last_print = Instant::now();
            }
            None => {}
        }
        Ok(())
    }

    pub fn finish(self) {
        if let Some(bar) = self.bar {
            bar.finish();
        }
    }
}

/// The status reports read so far: the run's progress, the failures roles announced, and
/// when each role was last heard from.
#[derive(Default)]
pub struct Watch {
    pub progress: Progress,
    failures: Vec<String>,
    last_heard: BTreeMap<String, Instant>,
    /// The roles whose tuning has been announced.
    tuning: HashSet<Role>,
}

impl Watch {
    /// Takes in the waiting reports, kills roles silent too long, then lets the supervisor
    /// deal with roles that exited.
    pub fn read(&mut self, status: &mut Inbox, supervisor: &mut Supervisor) -> Result<()> {
        for message in status.drain()? {
            let Message::Status(report) = message else {
                continue;
            };
            if let Some(name) = reporter(&report) {
                self.last_heard.insert(name, Instant::now());
            }
            if let Status::Warning { role, warning } = &report {
                supervisor.announce(&format!("warning from the {role}: {warning}"))?;
            }
            if let Status::Tuning { role } = report
                && self.tuning.insert(role)
            {
                let kept = qnet::tune_cache()
                    .map_or(String::new(), |dir| format!(", kept in {}", dir.display()));
                supervisor.say(
                    LogLevel::Info,
                    &format!(
                        "the {role} is warming up: tuning its GPU kernels where no tune is \
                         kept yet (CubeCL's autotune, once per device and shape{kept})"
                    ),
                )?;
            }
            if let Some(failure) = take(&mut self.progress, report) {
                self.failures.push(failure);
            }
        }
        let timeout = Duration::from_secs_f64(supervisor.config().run.heartbeat_timeout_s);
        supervisor.kill_silent(&self.last_heard, timeout);
        supervisor.check(
            &self.failures,
            &self.last_heard,
            self.progress.weights_version,
        )
    }
}

/// The name of the role a status report comes from.
fn reporter(report: &Status) -> Option<String> {
    match *report {
        Status::Buffer { .. } => Some(Role::Buffer.name().into()),
        Status::Learner { .. } => Some(Role::Learner.name().into()),
        Status::Tuning { role } => Some(role.name().into()),
        Status::Actor {
            actor, incarnation, ..
        } => Some(
            RoleId::Actor(ActorId {
                index: actor,
                incarnation,
            })
            .name(),
        ),
        Status::Failed { .. } | Status::Warning { .. } => None,
    }
}
