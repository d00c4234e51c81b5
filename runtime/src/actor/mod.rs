//! The actor role: episodes with the newest weights it has received. Observe, Q maps, the
//! hierarchical Q* choice under epsilon-greedy exploration, act in `sim`, reward, ship.
//!
//! A step is shipped once the next decision is made, because its label needs the next
//! state's value and a push's reward needs the goal's grasp Q after it: so a step travels
//! with everything the learner needs and its actor's initial priority. An episode ends with
//! its grasp; its end follows that grasp's step on the same topic.
//!
//! The actor's loop, its policy and its environments hand each other a step as it is made, so they
//! stay in one file.

mod heartbeat;
mod pictures;
mod ship;

use agent::{Agent, Choice, Situation};
use anyhow::{Context, Result};
use experience::Transition;
use mcaplog::RunLog;
use policy::{Decision, QMaps, trial_grasps};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sim::measure::{detect_change, most_crowded};
use sim::{Camera, Heightmaps, ObjectId, Primitive, Tabletop, workspace};
use wire::{Inbox, Message, Origin, Outbox, Role, Status, Topic, Transport, Weights};

use crate::stopwatch::{Stopwatch, status_mb};
use crate::{Lifeline, stop_requested};
use heartbeat::Heartbeat;
use pictures::log_pictures;
use rundir::ActorReport;
use rundir::backend::open_device;
use rundir::config::RunConfig;
use ship::{Shipper, Stream, Unlabelled};

/// Which actor this is: its index in the run and how many times that index was started.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ActorId {
    pub index: u32,
    pub incarnation: u32,
}

impl ActorId {
    /// The seed of this actor's scenes and exploration, derived from the run seed.
    pub fn seed(self, run_seed: u64) -> u64 {
        run_seed
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .wrapping_add(u64::from(self.index) << 20)
            .wrapping_add(u64::from(self.incarnation))
    }

    /// Episode ids unique across the run: index, incarnation, then a counter.
    fn episode(self, counter: u64) -> u64 {
        (u64::from(self.index) << 48) | (u64::from(self.incarnation) << 32) | counter
    }

    /// The ids of trial grasps, apart from the episodes' by the counter's top bit.
    fn trial(self, counter: u64) -> u64 {
        self.episode(counter | TRIAL_BIT)
    }
}

/// Set in the counter part of a trial grasp's episode id.
const TRIAL_BIT: u64 = 1 << 31;

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
            let choice = env.episode.is_some().then(|| choices.next()).flatten();
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
        if env.episode.is_none() {
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

/// A step completed by the decision after it (`None`: its scene ended, or its push lost the
/// goal), to be shipped.
type Completed = (Unlabelled, Option<Decision>);

/// One environment of an actor process: the scene it plays on, its exploration, its
/// episode under way, the step still waiting for the next decision, and its stream.
struct Environment<'a> {
    config: &'a RunConfig,
    id: ActorId,
    log: &'a RunLog,
    rng: ChaCha8Rng,
    scene_seed: u64,
    tabletop: Tabletop,
    camera: Camera,
    episode: Option<Episode>,
    unlabelled: Option<Unlabelled>,
    /// Grasps in a row that held nothing: a scene stuck for too long is replaced.
    failures_in_a_row: usize,
    /// The last episode's goal, kept for the scene's next episode under `goal_per_scene`.
    scene_goal: Option<ObjectId>,
    stream: Stream,
    report: ActorReport,
}

/// An episode under way: what the environment sees now, the goal, and its actions so far.
struct Episode {
    obs: Heightmaps,
    goal: ObjectId,
    step: u32,
}

impl<'a> Environment<'a> {
    fn new(config: &'a RunConfig, id: ActorId, log: &'a RunLog) -> Result<Self> {
        let seed = id.seed(config.seed);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let tabletop = Self::new_scene(config, seed, &mut rng)?;
        Ok(Self {
            config,
            id,
            log,
            rng,
            scene_seed: seed,
            camera: Camera::new(tabletop.grid()),
            tabletop,
            episode: None,
            unlabelled: None,
            failures_in_a_row: 0,
            scene_goal: None,
            stream: Stream::new(Origin {
                actor: id.index,
                incarnation: id.incarnation,
                seq: 0,
            }),
            report: ActorReport {
                actor: id.index,
                incarnation: id.incarnation,
                ..ActorReport::default()
            },
        })
    }

    fn new_scene(config: &RunConfig, seed: u64, rng: &mut ChaCha8Rng) -> Result<Tabletop> {
        let rows = config.rows.draw(rng);
        Ok(Tabletop::random_with_rows(&config.sim, config.objects, rows, seed)?.0)
    }

    /// Between episodes, starts one: on a new scene when this one has no goal left to take
    /// ([`Self::goal_candidates`]) or is stuck, for a candidate at random, or the most
    /// crowded one in the config's share of episodes (none while no candidate is seen: it
    /// tries again next time). Under `goal_per_scene` the scene's goal is taken again while
    /// it is seen, and its leaving the view ends the scene. A new scene dropped for an empty
    /// or stuck one ends the chain of the step waiting: returned, to ship as it is.
    fn episode_start(&mut self) -> Result<Option<Unlabelled>> {
        if self.episode.is_some() {
            return Ok(None);
        }
        let mut chain_end = None;
        let mut obs = self.camera.render(&self.tabletop);
        let mut candidates = self.goal_candidates(&obs);
        let kept = self
            .scene_goal
            .filter(|goal| self.config.goal_per_scene && candidates.contains(goal));
        let goal_left = self.config.goal_per_scene && self.scene_goal.is_some() && kept.is_none();
        let renew = candidates.is_empty()
            || goal_left
            || self.failures_in_a_row >= self.config.max_failures_per_scene;
        if renew {
            // The goal's leaving is no end of the chain: the step waiting bootstraps on the
            // fresh drop's first decision, as the original's label reads the next image,
            // which keeps the grasp Q on the scale Q* is set for. An empty or stuck scene's
            // last step ships as it is.
            if !goal_left {
                chain_end = self.unlabelled.take();
            }
            self.scene_seed = self.scene_seed.wrapping_add(1);
            self.tabletop = Self::new_scene(self.config, self.scene_seed, &mut self.rng)?;
            obs = self.camera.render(&self.tabletop);
            candidates = self.goal_candidates(&obs);
            self.failures_in_a_row = 0;
        }
        let goal = match kept {
            Some(goal) if !renew => Some(goal),
            _ => self.draw_goal(&obs, &candidates),
        };
        self.scene_goal = goal;
        if let Some(goal) = goal {
            self.episode = Some(Episode { obs, goal, step: 0 });
        }
        Ok(chain_end)
    }

    /// A goal among `candidates`: the most crowded in the config's share of draws, else one
    /// at random.
    fn draw_goal(&mut self, obs: &Heightmaps, candidates: &[ObjectId]) -> Option<ObjectId> {
        // No draw at a share of 0: the episodes' goals stay those of the seed without it.
        let share = self.config.crowded_goals;
        if share > 0.0 && self.rng.random::<f64>() < share {
            most_crowded(obs, candidates)
        } else {
            candidates
                .get(self.rng.random_range(0..candidates.len().max(1)))
                .copied()
        }
    }

    /// The objects an episode may take as its goal: those seen, under `goals_over_workspace`
    /// only those whose centre lies over the workspace.
    fn goal_candidates(&self, obs: &Heightmaps) -> Vec<ObjectId> {
        let mut seen = obs.visible_ids();
        if self.config.goals_over_workspace {
            seen.retain(|&id| {
                self.tabletop.object(id).is_some_and(|o| {
                    let centre = o.pose.translation;
                    workspace::contains(centre.x, centre.y)
                })
            });
        }
        seen
    }

    /// What the agent decides on in this environment, while an episode is under way.
    fn situation(&mut self) -> Option<Situation<'_>> {
        let episode = self.episode.as_ref()?;
        Some(Situation {
            obs: &episode.obs,
            goal: episode.goal,
            pushes_so_far: episode.step as usize,
            epsilon: self.config.epsilon(self.id.index, self.report.actions),
            rng: &mut self.rng,
        })
    }

    /// Acts on `choice` (made with weights `weights_version`): a push goes on with the
    /// episode, a grasp ends it. Returns the steps the choice completed.
    fn act(&mut self, choice: Choice, weights_version: u64) -> Result<Vec<Completed>> {
        let Episode { obs, goal, step } = self.episode.take().expect("acting in an episode");
        let pictures_ns = self.pictures(&obs, &choice)?;
        let Choice {
            decision, grasp, ..
        } = choice;
        let mut completed: Vec<Completed> = self
            .unlabelled
            .take()
            .map(|p| (p, Some(decision)))
            .into_iter()
            .collect();
        if decision.action.primitive == Primitive::Grasp && self.config.grasp_trials > 0 {
            completed.extend(self.trials(&obs, goal, &grasp, &decision, weights_version)?);
        }
        let outcome = self.tabletop.act(&decision.action, &obs)?;
        self.report.actions += 1;
        let transition = Transition {
            episode: self.id.episode(self.report.episodes),
            step,
            goal,
            obs,
            action: decision.action,
            reward: 0.0,
            grasped: outcome.grasped,
            next_value: None,
            next: None,
        };
        if decision.action.primitive == Primitive::Push {
            let obs = self.camera.render(&self.tabletop);
            let push = Unlabelled {
                push_changed: Some(detect_change(&transition.obs, &obs, goal)),
                transition,
                decision,
                ends: None,
                scene_seed: self.scene_seed,
                pictures_ns,
                weights_version,
            };
            if self.config.goal_lost_ends_episode && self.tabletop.object(goal).is_none() {
                // Nothing after this push can pick the goal: it is the episode's last step.
                self.report.episodes += 1;
                completed.push((push.ending_episode(), None));
                return Ok(completed);
            }
            self.unlabelled = Some(push);
            self.episode = Some(Episode {
                obs,
                goal,
                step: step + 1,
            });
            return Ok(completed);
        }
        self.failures_in_a_row = if outcome.grasped.is_some() {
            0
        } else {
            self.failures_in_a_row + 1
        };
        let grasp = Unlabelled::grasp(
            transition,
            decision,
            false,
            self.scene_seed,
            pictures_ns,
            weights_version,
        );
        self.report.episodes += 1;
        self.report.goal_grasps += u64::from(grasp.transition.reward > 0.0);
        self.unlabelled = Some(grasp);
        Ok(completed)
    }

    /// The pictures of this step, every `image_every` episodes: when they were logged.
    fn pictures(&self, obs: &Heightmaps, choice: &Choice) -> Result<Option<u64>> {
        let every = self.config.logging.image_every;
        (every > 0 && self.report.episodes.is_multiple_of(every))
            .then(|| {
                log_pictures(
                    self.log,
                    &self.tabletop,
                    obs,
                    &choice.grasp,
                    choice.push.as_ref(),
                )
            })
            .transpose()
    }

    /// Grasps tried on copies of the scene beside the executed one (`grasp_trials`), each
    /// an episode of its own, completed at once.
    fn trials(
        &mut self,
        obs: &Heightmaps,
        goal: ObjectId,
        grasp: &QMaps,
        decision: &Decision,
        weights_version: u64,
    ) -> Result<Vec<Completed>> {
        let trials = trial_grasps(
            obs,
            goal,
            grasp,
            decision,
            self.config.grasp_trials,
            &self.config.policy,
            &mut self.rng,
        )?;
        let mut completed = Vec::with_capacity(trials.len());
        for trial in trials {
            let outcome = self.tabletop.replica().act(&trial.action, obs)?;
            let transition = Transition {
                episode: self.id.trial(self.report.trials),
                step: 0,
                goal,
                obs: obs.clone(),
                action: trial.action,
                reward: 0.0,
                grasped: outcome.grasped,
                next_value: None,
                next: None,
            };
            self.report.trials += 1;
            let unlabelled = Unlabelled::grasp(
                transition,
                trial,
                true,
                self.scene_seed,
                None,
                weights_version,
            );
            // A successful trial bootstraps on the executed grasp's view of this scene (its
            // goal grasp Q), standing in for the scene it would leave.
            completed.push((unlabelled, Some(*decision)));
        }
        Ok(completed)
    }
}

#[cfg(test)]
mod tests;
