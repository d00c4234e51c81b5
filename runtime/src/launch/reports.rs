//! The roles' reports read back at the end of a run, and the run's summary line.

use std::path::Path;

use anyhow::Result;
use wire::Role;

use crate::actor::ActorId;
use crate::role::RoleId;
use crate::supervisor::Supervisor;
use rundir::config::RunConfig;
use rundir::run_dir::RunDir;
use rundir::{ActorReport, BufferReport, LearnerReport, Summary, percent, read_json};

/// The report at `path`, or `missing()` when the role wrote none (it died); a report that
/// cannot be read is an error naming it.
pub(super) fn report_or<T: serde::de::DeserializeOwned>(
    path: &Path,
    missing: impl Fn() -> T,
) -> Result<T> {
    if path.exists() {
        read_json(path)
    } else {
        Ok(missing())
    }
}

/// What the buffer counted lost to the fault of role `role`: the gaps in the streams of a
/// crashed actor process's environments, or what the buffer that took over from a crashed
/// one found missing.
pub(super) fn lost_in_fault(buffer: &BufferReport, role: &str, config: &RunConfig) -> Option<u64> {
    let streams: Vec<u64> = buffer
        .streams
        .iter()
        .filter(|s| {
            let process = ActorId {
                index: config.layout().process_of(s.actor),
                incarnation: s.incarnation,
            };
            RoleId::Actor(process).name() == role
        })
        .map(|s| s.missing)
        .collect();
    if !streams.is_empty() {
        return Some(streams.iter().sum());
    }
    buffer
        .restart_losses
        .iter()
        .find(|&(&next, _)| next > 0 && RoleId::Buffer(next - 1).name() == role)
        .map(|(_, &lost)| lost)
}

/// Steps that the actors this launch started, and stopped in order, sent and the buffer
/// never received ([`BufferReport::unreceived`]). Not those of a launch before, which may
/// have ended hung, its roles stopping by themselves in any order; none after a restart of
/// the buffer, which counts its losses apart.
pub(super) fn unreceived_steps(
    supervisor: &Supervisor,
    buffer: &BufferReport,
    actors: &[ActorReport],
) -> u64 {
    if supervisor.buffer() != RoleId::Buffer(0) {
        return 0;
    }
    let config = supervisor.config();
    let stopped_here: Vec<ActorReport> = actors
        .iter()
        .filter(|r| {
            supervisor.started_actor(ActorId {
                index: config.layout().process_of(r.actor),
                incarnation: r.incarnation,
            })
        })
        .cloned()
        .collect();
    buffer.unreceived(&stopped_here)
}

/// The reports of actors that stopped cleanly, in index and incarnation order.
pub(super) fn actor_reports(dir: &RunDir) -> Result<Vec<ActorReport>> {
    let mut reports = Vec::new();
    for entry in std::fs::read_dir(dir.reports())? {
        let path = entry?.path();
        if path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with(Role::Actor.name()))
        {
            reports.push(read_json::<ActorReport>(&path)?);
        }
    }
    reports.sort_by_key(|r| (r.actor, r.incarnation));
    Ok(reports)
}

pub(super) fn print_summary(summary: &Summary, dir: &RunDir) {
    println!(
        "{}: {} episodes, goal grasp success first 30 {}, last 30 {}, {} steps received ({} lost{}), {} learner updates{}, {} restarts, {:.1} s; checkpoint, buffer snapshot and curve.csv in {}",
        match (&summary.failure, summary.interrupted) {
            (Some(_), _) => "failed",
            (None, true) => "interrupted",
            (None, false) => "done",
        },
        summary.buffer.episodes,
        percent(summary.buffer.success_first30),
        percent(summary.buffer.success_last30),
        summary.buffer.steps_received,
        summary.lost(),
        match summary.buffer.lost_in_restarts {
            0 => String::new(),
            n => format!(", {n} messages lost to restarts of the buffer"),
        },
        summary.learner.updates,
        learner_pace(&summary.learner),
        summary.restarts,
        summary.wall_s,
        dir.path().display()
    );
    crate::hosts::print_hosts(&summary.hosts);
}

/// The learner's pace in a summary line: its updates a second, and how much of the time it
/// was updating (near all of it, the learner paced the run; else the actors did) with its
/// updates a second of that time.
fn learner_pace(learner: &LearnerReport) -> String {
    match (
        learner.updates_per_s(),
        learner.busy_share(),
        learner.updates_per_busy_s(),
    ) {
        (Some(rate), Some(share), Some(own)) => format!(
            " ({rate:.1}/s, busy {:.0}% of the time: {own:.1} a busy second)",
            100.0 * share
        ),
        _ => String::new(),
    }
}
