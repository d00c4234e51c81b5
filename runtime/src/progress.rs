//! What the launcher knows of a run while it goes ([`Progress`], from every role's status
//! reports), how it shows it ([`Display`]), and what it says of the run at the end
//! ([`Summary`]).

use std::collections::{BTreeMap, HashSet};
use std::io::IsTerminal;
use std::time::{Duration, Instant};

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use mcaplog::LogLevel;
use serde::{Deserialize, Serialize};
use wire::{Inbox, Message, Role, Status};

use crate::actor::{ActorId, ActorReport};
use crate::buffer::BufferReport;
use crate::learner::LearnerReport;
use crate::memory::MemorySampler;
use crate::read_json;
use crate::record::LAUNCHER_PROGRESS;
use crate::role::RoleId;
use crate::run_dir::RunDir;
use crate::supervisor::{Fault, Supervisor};

/// What the launcher saw of the run, from the roles' status reports.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Progress {
    pub episodes: u64,
    pub steps_received: u64,
    pub success_last30: Option<f64>,
    pub stored: u64,
    pub capacity: u64,
    pub relabelled: u64,
    pub lost: u64,
    pub updates: u64,
    pub weights_version: u64,
    pub loss: Option<f32>,
    /// Each actor index's newest report. (Absent from logs written before it: empty.)
    #[serde(default)]
    pub actors: BTreeMap<u32, ActorProgress>,
}

/// What an actor last reported.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ActorProgress {
    pub incarnation: u32,
    pub episodes: u64,
    pub steps_sent: u64,
    /// The weights it acts with.
    pub weights_version: u64,
}

impl Progress {
    /// Takes a report in; a failure report is returned as text.
    pub fn take(&mut self, status: Status) -> Option<String> {
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
                self.steps_received = steps_received;
                self.episodes = episodes;
                self.success_last30 = success_last30;
                self.stored = stored;
                self.capacity = capacity;
                self.relabelled = relabelled;
                self.lost = lost;
            }
            Status::Learner {
                updates,
                weights_version,
                loss,
            } => {
                self.updates = updates;
                self.weights_version = weights_version;
                self.loss = loss;
            }
            Status::Actor {
                actor,
                incarnation,
                episodes,
                steps_sent,
                weights_version,
            } => {
                let progress = ActorProgress {
                    incarnation,
                    episodes,
                    steps_sent,
                    weights_version,
                };
                self.actors.insert(actor, progress);
            }
            Status::Failed { role, error } => return Some(format!("{role}: {error}")),
            Status::Tuning { .. } | Status::Warning { .. } => {}
        }
        None
    }

    /// The oldest weights an actor acts with, once every actor has reported.
    pub fn oldest_actor_weights(&self) -> Option<u64> {
        self.actors.values().map(|a| a.weights_version).min()
    }

    pub fn line(&self, updates_per_s: f64) -> String {
        let actors = self
            .oldest_actor_weights()
            .map_or(String::new(), |v| format!(" (actors from v{v})"));
        format!(
            "goal grasp success (last 30) {} | {updates_per_s:.1} updates/s | buffer {}/{} | weights v{}{actors}",
            percent(self.success_last30),
            self.stored,
            self.capacity,
            self.weights_version
        )
    }
    /// The buffer's counts as its last status report gave them.
    pub fn buffer_report(&self) -> BufferReport {
        BufferReport {
            steps_received: self.steps_received,
            episodes: self.episodes,
            success_last30: self.success_last30,
            relabelled: self.relabelled,
            ..BufferReport::default()
        }
    }

    /// The learner's counts as its last status report gave them.
    pub fn learner_report(&self) -> LearnerReport {
        LearnerReport {
            updates: self.updates,
            weights_version: self.weights_version,
            last_loss: self.loss,
            ..LearnerReport::default()
        }
    }
}

/// What a run says about itself when it ends, however it ends (`<run>/summary.json`).
#[derive(Debug, Serialize, Deserialize)]
pub struct Summary {
    pub run_id: String,
    /// Actor processes on this host.
    pub actors: u32,
    /// Environments each actor process stepped.
    #[serde(default = "crate::config::one_environment")]
    pub envs_per_actor: u32,
    /// Roles started again after a failure: actors, the buffer and the learner.
    pub restarts: u32,
    pub interrupted: bool,
    pub wall_s: f64,
    /// The buffer's and the learner's reports; for a role that died without writing one, the
    /// counts of its last status report (the buffer's then has no per-stream counts).
    pub buffer: BufferReport,
    pub learner: LearnerReport,
    /// The reports of actors' environments that stopped cleanly (a killed one writes none; its steps are
    /// accounted for by the buffer's per-incarnation counts).
    pub actors_reports: Vec<ActorReport>,
    /// Steps those actors sent that the buffer never received at the end of their streams
    /// (`BufferReport::unreceived`). (Absent from summaries written before: none.)
    #[serde(default)]
    pub unreceived_steps: u64,
    /// Every role that failed, in order: restarted (the run went on) or not (the run ended).
    /// (Absent from summaries written before: none.)
    #[serde(default)]
    pub faults: Vec<Fault>,
    /// Why the run ended before its budget, when a fault ended it.
    #[serde(default)]
    pub failure: Option<String>,
    /// The hosts that joined the run (`train --listen`): which actors each ran, what arrived
    /// from it, what was refused or lost in flight. (Absent from summaries written before:
    /// none.)
    #[serde(default)]
    pub hosts: Vec<bridge::HostReport>,
}

impl Summary {
    /// Messages from this host's actors that never reached the buffer, unexplained: gaps in
    /// their streams, and steps missing at their ends.
    pub fn lost(&self) -> u64 {
        self.buffer.lost() + self.unreceived_steps
    }

    /// The summary of the run in `dir`, if it wrote one.
    pub fn read(dir: &RunDir) -> Result<Option<Summary>> {
        let path = dir.summary();
        if !path.exists() {
            return Ok(None);
        }
        read_json(&path).map(Some)
    }

    /// Whether the run ended by itself at its budget (faults it recovered from allowed).
    pub fn finished(&self) -> bool {
        !self.interrupted && self.failure.is_none()
    }
}

/// A share as a whole percentage, or "-" when there is none yet.
pub fn percent(share: Option<f64>) -> String {
    share.map_or("-".into(), |s| format!("{:.0}%", 100.0 * s))
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
            if let Some(failure) = self.progress.take(report) {
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
