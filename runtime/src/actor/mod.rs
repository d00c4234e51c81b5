//! The actor role: episodes with the newest weights it has received. Observe, Q maps, the
//! hierarchical Q* choice under epsilon-greedy exploration, act in `sim`, reward, ship.
//!
//! A step is shipped once the next decision is made, because its label needs the next
//! state's value and a push's reward needs the goal's grasp Q after it: so a step travels
//! with everything the learner needs and its actor's initial priority. An episode ends with
//! its grasp; its end follows that grasp's step on the same topic.
//!
//! This file is the process: its weights, its loop and one tick over its environments;
//! `environment` holds the episode rules of one scene (which goal, when a scene is new,
//! what an action completes).

mod environment;
mod heartbeat;
mod id;
mod pictures;
mod ship;

use agent::Agent;
use anyhow::{Context, Result};
use mcaplog::RunLog;
use rayon::prelude::*;
use wire::{Inbox, Message, Outbox, Role, Status, Topic, Transport, Weights};

use crate::stopwatch::{Stopwatch, status_mb};
use crate::{Lifeline, stop_requested};
use environment::{Completed, Environment};
use heartbeat::Heartbeat;
use rundir::ActorReport;
use rundir::backend::open_device;
use rundir::config::RunConfig;
use ship::Shipper;

pub use id::ActorId;

/// Runs its environments' episodes until the launcher says stop (or the launcher is gone);
/// returns what each did. `first`: the process's first environment (the others follow it,
/// `config.envs_per_actor` in all).
pub fn run(
    transport: &dyn Transport,
    config: &RunConfig,
    first: ActorId,
    log: &RunLog,
    lifeline: &Lifeline,
) -> Result<Vec<ActorReport>> {
    let mut control = Inbox::open(transport, Topic::Control)?;
    let mut policy = Policy::new(transport, config, log)?;
    let mut envs = (0..config.envs_per_actor)
        .map(|j| {
            let id = ActorId {
                index: first.index + j,
                ..first
            };
            Environment::new(config, id, log)
        })
        .collect::<Result<Vec<_>>>()?;
    let heartbeat = Heartbeat::new(
        Outbox::open(transport, Topic::Status)?,
        statuses(&envs, policy.version),
    );
    let steps = Outbox::open(transport, Topic::Steps)?;
    let mut shipper = Shipper::new(log, steps, heartbeat, config);
    // Nothing to act with until the learner's first weights arrive.
    if !policy.first_weights(lifeline, &mut control, shipper.heartbeat())? {
        return Ok(envs.into_iter().map(|env| env.report).collect());
    }
    let acting = Stopwatch::start();
    // Stops between actions, not only between episodes: a push chain can be long.
    while !lifeline.lost() && !stop_requested(&mut control, Role::Actor)? {
        policy.take_newest()?;
        let ended = tick(&mut envs, &policy, &mut shipper)?;
        shipper
            .heartbeat()
            .report(statuses(&envs, policy.version), &ended)?;
    }
    // A step still waiting for its next state is not sent: its label would be a guess. Its
    // episode's earlier steps reach the buffer, which keeps or flushes them.
    let (acting_s, cpu_s) = (acting.wall_s(), acting.cpu_s());
    let own = lifeline.own_process();
    let peak_rss_mb = own.then(|| status_mb("self", "VmHWM:")).flatten();
    let share = f64::from(config.envs_per_actor);
    Ok(envs
        .into_iter()
        .map(|env| ActorReport {
            steps_sent: env.stream.steps_sent,
            weights_version: policy.version,
            acting_s,
            cpu_s: own.then_some(cpu_s / share),
            peak_rss_mb: peak_rss_mb.map(|mb| mb / share),
            ..env.report
        })
        .collect())
}

/// Each environment's progress, as the supervisor reads it.
fn statuses(envs: &[Environment<'_>], weights_version: u64) -> Vec<Status> {
    envs.iter()
        .map(|env| Status::Actor {
            actor: env.id.index,
            incarnation: env.id.incarnation,
            episodes: env.report.episodes,
            steps_sent: env.stream.steps_sent,
            weights_version,
        })
        .collect()
}

/// One action in every environment: those between episodes start one, those in one decide
/// together (one batch of Q maps), then all act at once, their scenes spread over the
/// cores, and what they completed is shipped. Returns the environments whose episode ended.
fn tick(
    envs: &mut [Environment<'_>],
    policy: &Policy,
    shipper: &mut Shipper<'_>,
) -> Result<Vec<usize>> {
    for env in envs.iter_mut() {
        if let Some(chain_end) = env.episode_start()? {
            shipper.ship(&mut env.stream, chain_end, None)?;
        }
    }
    let situations = envs.iter_mut().filter_map(Environment::situation).collect();
    let mut choices = policy.agent.decide_each(situations)?.into_iter();
    let work: Vec<_> = envs
        .iter_mut()
        .map(|env| {
            let choice = env.in_episode().then(|| choices.next()).flatten();
            (env, choice)
        })
        .collect();
    let version = policy.version;
    let completed: Vec<Option<Vec<Completed>>> = work
        .into_par_iter()
        .map(|(env, choice)| choice.map(|c| env.act(c, version)).transpose())
        .collect::<Result<_>>()?;
    let mut ended = Vec::new();
    for (i, (env, completed)) in envs.iter_mut().zip(completed).enumerate() {
        let Some(completed) = completed else {
            continue;
        };
        for (step, next) in completed {
            shipper.ship(&mut env.stream, step, next.as_ref())?;
        }
        if !env.in_episode() {
            ended.push(i);
        }
    }
    Ok(ended)
}

/// The actor's agent and where new weights come from.
struct Policy {
    agent: Agent,
    weights: Inbox,
    version: u64,
}

impl Policy {
    fn new(transport: &dyn Transport, config: &RunConfig, log: &RunLog) -> Result<Self> {
        let device = open_device(config.backend.actors, "actors", log)?;
        let agent = Agent::new(
            &config.net,
            &config.sim,
            config.policy.clone(),
            config.mode(),
            &device,
        );
        Ok(Self {
            agent,
            weights: Inbox::open(transport, Topic::Weights)?,
            version: 0,
        })
    }

    /// Takes the newest weights waiting, if any: whether there were.
    fn take_newest(&mut self) -> Result<bool> {
        let mut newest: Option<Weights> = None;
        for message in self.weights.drain()? {
            if let Message::Weights(w) = message {
                newest = Some(w);
            }
        }
        let Some(w) = newest else {
            return Ok(false);
        };
        self.agent
            .load_weights(&w.bytes)
            .context("loading the learner's weights")?;
        self.version = w.version;
        Ok(true)
    }

    /// Waits for the learner's first weights, heard meanwhile; false if the run stopped
    /// first.
    fn first_weights(
        &mut self,
        lifeline: &Lifeline,
        control: &mut Inbox,
        heartbeat: &mut Heartbeat,
    ) -> Result<bool> {
        while !self.take_newest()? {
            if lifeline.lost() || stop_requested(control, Role::Actor)? {
                return Ok(false);
            }
            heartbeat.beat()?;
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        Ok(true)
    }
}
