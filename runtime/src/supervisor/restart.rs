//! Roles that exited or fell silent: why each did, and whether it starts again as its next
//! incarnation or the run ends.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use wire::Role;

use super::fault::last_error;
use super::{HUNG, MAX_RESTARTS, MAX_ROLE_RESTARTS, QUIET, RESUME_HINT, Slot, Supervisor, beat};
use crate::role::RoleId;

impl Supervisor {
    /// Deals with roles that exited: restarts each as its next incarnation, until one fails
    /// too often, or twice the same way before it first reported (then the run ends with
    /// the reason). `last_heard`: when each reporter was last heard from.
    /// `weights_version`: the newest the learner reported, which a restarted one passes.
    pub fn check(
        &mut self,
        failures: &[String],
        last_heard: &BTreeMap<String, Instant>,
        weights_version: u64,
    ) -> Result<()> {
        beat(&self.dir, &mut self.last_beat)?;
        let mut exited = Vec::new();
        for slot in self.slots.iter_mut().filter(|s| !s.done) {
            if let Some(outcome) = slot.worker.finished() {
                slot.done = true;
                let reported = last_heard
                    .get(&slot.spec.reporter())
                    .is_some_and(|&at| at >= slot.started);
                exited.push((slot.spec, slot.hung.take().map_or(outcome, Err), reported));
            }
        }
        for (spec, outcome, reported) in exited {
            let why = self.cause(spec, outcome, failures);
            self.refuse_a_loop(spec, &why, reported)?;
            let RoleId::Actor(id) = spec else {
                self.restart_singleton(spec, why, weights_version)?;
                continue;
            };
            let crashes = self.crashes.entry(id.index).or_insert(0);
            *crashes += 1;
            let crashes = *crashes;
            self.record_fault(spec.name(), &why, crashes <= MAX_RESTARTS);
            if crashes > MAX_RESTARTS {
                bail!(
                    "actor {} crashed {crashes} times; giving up: {why}",
                    id.index
                );
            }
            self.announce(&format!("{} failed: {why}; starting it again", spec.name()))?;
            self.restarts += 1;
            self.start(spec.next_incarnation())?;
        }
        Ok(())
    }

    /// Why a role exited: killed for its silence, the error its log ends with (a process's),
    /// the failure it announced (a thread's), or how its process ended.
    fn cause(&self, spec: RoleId, outcome: Result<(), String>, failures: &[String]) -> String {
        let hung = outcome.as_ref().err().filter(|why| why.contains(HUNG));
        hung.cloned()
            .or_else(|| last_error(&self.dir.log(&spec.name())))
            .or_else(|| {
                failures
                    .iter()
                    .find(|f| f.starts_with(&spec.name()))
                    .cloned()
            })
            .or_else(|| outcome.err())
            .unwrap_or_else(|| "exited before it was told to".into())
    }

    /// Ends the run when a role failed before it first reported, as its predecessor did and
    /// for the same reason: started again, it would fail again. A role killed for its
    /// silence did not fail by itself (a machine too busy for it to start in time): it is
    /// restarted as any crash.
    fn refuse_a_loop(&mut self, spec: RoleId, why: &str, reported: bool) -> Result<()> {
        let lineage = match spec {
            RoleId::Actor(id) => (Role::Actor.name(), id.index),
            other => (other.kind().name(), 0),
        };
        if reported || why.contains(HUNG) {
            self.startup_failures.remove(&lineage);
            return Ok(());
        }
        if self.startup_failures.get(&lineage).map(String::as_str) == Some(why) {
            self.record_fault(spec.name(), why, false);
            bail!(
                "the {} failed twice the same way as it started, so it is not started again: \
                 {why} (see {})",
                spec.name(),
                self.dir.log(&spec.name()).display()
            );
        }
        self.startup_failures.insert(lineage, why.to_string());
        Ok(())
    }

    /// Starts the buffer or the learner again from its newest saved state, after it exited
    /// (or was killed for its silence); gives up on the run after [`MAX_ROLE_RESTARTS`].
    fn restart_singleton(&mut self, spec: RoleId, why: String, weights_version: u64) -> Result<()> {
        let restart = spec.incarnation() < MAX_ROLE_RESTARTS;
        self.record_fault(spec.name(), &why, restart);
        if !restart {
            bail!(
                "the {} failed {} times; giving up: {why} (see {}); {RESUME_HINT}",
                spec.kind(),
                spec.incarnation() + 1,
                self.dir.log(&spec.name()).display()
            );
        }
        self.announce(&format!(
            "the {} failed: {why}; starting it again",
            spec.name()
        ))?;
        self.restarts += 1;
        let next = spec.next_incarnation();
        match next {
            RoleId::Learner(_) => {
                self.learner = next;
                self.weights_after = weights_version;
            }
            _ => self.buffer = next,
        }
        self.start(next)
    }

    /// Kills every role process that has sent no status report for `timeout` (since it
    /// started, when it never did): the next [`Supervisor::check`] handles it as a crash.
    /// Roles wait on those upstream (everyone on the buffer; actors also on the learner,
    /// whose pace lets their steps in): while one upstream is quiet, those downstream are
    /// not judged, and their silence counts from its latest start. An actor held back by
    /// the buffer's rate limiter (a slow learner), or on a joined host by its link, reports
    /// from its waiting send, so each actor is judged by its own silence.
    /// (A thread cannot be killed; the threads wiring is for tests and small runs.)
    pub fn kill_silent(&mut self, last_heard: &BTreeMap<String, Instant>, timeout: Duration) {
        let silence = |slot: &Slot, since: Instant| {
            last_heard
                .get(&slot.spec.reporter())
                .map_or(since, |&at| at.max(since))
                .elapsed()
        };
        let mut upstream_started = None;
        for kind in [Role::Buffer, Role::Learner, Role::Actor] {
            for slot in self
                .slots
                .iter_mut()
                .filter(|s| !s.done && s.hung.is_none() && s.spec.kind() == kind)
            {
                let since = upstream_started.map_or(slot.started, |up| slot.started.max(up));
                let silent = silence(slot, since);
                if silent > timeout && slot.worker.pid().is_some() {
                    slot.worker.kill();
                    slot.hung = Some(format!(
                        "{HUNG} for {:.0} s and was killed",
                        silent.as_secs_f64()
                    ));
                }
            }
            let live: Vec<&Slot> = self
                .slots
                .iter()
                .filter(|s| !s.done && s.spec.kind() == kind)
                .collect();
            if live
                .iter()
                .any(|s| s.hung.is_some() || silence(s, s.started) > QUIET)
            {
                return;
            }
            upstream_started = live.iter().map(|s| s.started).chain(upstream_started).max();
        }
    }
}
