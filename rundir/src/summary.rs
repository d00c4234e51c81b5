//! What a run says of itself: the launcher's progress as it goes (logged every second) and
//! the summary it writes when the run ends, however it ends (`summary.json`).

use std::collections::BTreeMap;

use anyhow::Result;
use serde::{Deserialize, Serialize};

use crate::files::read_json;
use crate::reports::{ActorReport, BufferReport, Fault, HostReport, LearnerReport};
use crate::run_dir::RunDir;

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

impl Progress {
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

/// What an actor last reported.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ActorProgress {
    pub incarnation: u32,
    pub episodes: u64,
    pub steps_sent: u64,
    /// The weights it acts with.
    pub weights_version: u64,
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
    pub hosts: Vec<HostReport>,
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
