//! The actor role: episodes with the newest weights it has received. Observe, Q maps, the
//! hierarchical Q* choice under epsilon-greedy exploration, act in `sim`, reward, ship.
//!
//! A step is shipped once the next decision is made, because its label needs the next
//! state's value and a push's reward needs the goal's grasp Q after it: so a step travels
//! with everything the learner needs and its actor's initial priority. An episode ends with
//! its grasp; its end follows that grasp's step on the same topic.

mod pictures;
mod ship;

use agent::{Agent, Choice};
use anyhow::{Context, Result};
use experience::Transition;
use mcaplog::RunLog;
use policy::{Decision, QMaps, trial_grasps};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::measure::detect_change;
use sim::{Camera, Heightmaps, ObjectId, Primitive, Tabletop};
use wire::{Inbox, Message, Origin, Outbox, Role, Status, Topic, Transport, Weights};

use crate::backend::open_device;
use crate::config::RunConfig;
use crate::stopwatch::Stopwatch;
use crate::{Lifeline, stop_requested};
use pictures::log_pictures;
use ship::{Shipper, Unlabelled};

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

/// What an actor did, written to the run directory when it stops.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ActorReport {
    pub actor: u32,
    pub incarnation: u32,
    pub episodes: u64,
    pub actions: u64,
    /// Steps shipped to the buffer (episode ends not counted).
    pub steps_sent: u64,
    pub goal_grasps: u64,
    /// Grasps tried on copies of the scene (`grasp_trials`), not counted in `actions`.
    #[serde(default)]
    pub trials: u64,
    pub weights_version: u64,
    /// Seconds from the first weights received to the stop: the time `actions` took.
    pub acting_s: f64,
    /// CPU seconds the actor's process used over `acting_s`, all its threads (none for an
    /// actor in a thread of the launcher, whose process the other roles share).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_s: Option<f64>,
}

/// Runs episodes until the launcher says stop (or the launcher is gone); returns what it did.
pub fn run(
    transport: &dyn Transport,
    config: &RunConfig,
    id: ActorId,
    log: &RunLog,
    lifeline: &Lifeline,
) -> Result<ActorReport> {
    let mut control = Inbox::open(transport, Topic::Control)?;
    let mut status = Outbox::open(transport, Topic::Status)?;
    let origin = Origin {
        actor: id.index,
        incarnation: id.incarnation,
        seq: 0,
    };
    let steps = Outbox::open(transport, Topic::Steps)?;
    let mut shipper = Shipper::new(log, steps, origin, config);
    let mut policy = Policy::new(transport, config, log)?;
    let mut report = ActorReport {
        actor: id.index,
        incarnation: id.incarnation,
        ..ActorReport::default()
    };
    // Nothing to act with until the learner's first weights arrive.
    if !policy.refresh(true, lifeline, &mut control)? {
        return Ok(report);
    }
    let acting = Stopwatch::start();
    let mut play = Play::new(config, id, log)?;
    while !lifeline.lost() && !stop_requested(&mut control, Role::Actor)? {
        policy.refresh(false, lifeline, &mut control)?;
        shipper.weights_version = policy.version;
        let Some((obs, goal)) = play.episode_start(&mut shipper)? else {
            continue;
        };
        let ended = play.episode(obs, goal, &policy, &mut shipper, &mut report, &mut || {
            Ok(lifeline.lost() || stop_requested(&mut control, Role::Actor)?)
        })?;
        if !ended {
            break;
        }
        status.send(&Message::Status(Status::Actor {
            actor: id.index,
            incarnation: id.incarnation,
            episodes: report.episodes,
            steps_sent: shipper.steps_sent,
            weights_version: policy.version,
        }))?;
    }
    // A step still waiting for its next state is not sent: its label would be a guess. Its
    // episode's earlier steps reach the buffer, which keeps or flushes them.
    report.steps_sent = shipper.steps_sent;
    report.weights_version = policy.version;
    report.acting_s = acting.wall_s();
    report.cpu_s = lifeline.own_process().then(|| acting.cpu_s());
    Ok(report)
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
            config.side(),
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

    /// Takes the newest weights waiting, if any; with `wait`, blocks until some arrived.
    fn refresh(&mut self, wait: bool, lifeline: &Lifeline, control: &mut Inbox) -> Result<bool> {
        loop {
            let mut newest: Option<Weights> = None;
            for message in self.weights.drain()? {
                if let Message::Weights(w) = message {
                    newest = Some(w);
                }
            }
            if let Some(w) = newest {
                self.agent
                    .load_weights(&w.bytes)
                    .context("loading the learner's weights")?;
                self.version = w.version;
                return Ok(true);
            }
            if !wait {
                return Ok(false);
            }
            if lifeline.lost() || stop_requested(control, Role::Actor)? {
                return Ok(false);
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
    }
}

/// The actor's world between episodes: the scene it plays on, its exploration, and the step
/// still waiting for the next decision.
struct Play<'a> {
    config: &'a RunConfig,
    id: ActorId,
    log: &'a RunLog,
    rng: ChaCha8Rng,
    scene_seed: u64,
    tabletop: Tabletop,
    camera: Camera,
    unlabelled: Option<Unlabelled>,
    /// Grasps in a row that held nothing: a scene stuck for too long is replaced.
    failures_in_a_row: usize,
}

impl<'a> Play<'a> {
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
            unlabelled: None,
            failures_in_a_row: 0,
        })
    }

    fn new_scene(config: &RunConfig, seed: u64, rng: &mut ChaCha8Rng) -> Result<Tabletop> {
        let rows = config.rows.draw(rng);
        Ok(Tabletop::random_with_rows(&config.sim, config.objects, rows, seed)?.0)
    }

    /// The observation and goal an episode starts from: a new scene when this one is
    /// cleared or stuck (a waiting step then ends its chain), a visible object at random.
    fn episode_start(&mut self, shipper: &mut Shipper) -> Result<Option<(Heightmaps, ObjectId)>> {
        let mut obs = self.camera.render(&self.tabletop);
        if obs.visible_ids().is_empty()
            || self.failures_in_a_row >= self.config.max_failures_per_scene
        {
            if let Some(p) = self.unlabelled.take() {
                shipper.ship(p, None)?;
            }
            self.scene_seed = self.scene_seed.wrapping_add(1);
            self.tabletop = Self::new_scene(self.config, self.scene_seed, &mut self.rng)?;
            obs = self.camera.render(&self.tabletop);
            self.failures_in_a_row = 0;
        }
        let visible = obs.visible_ids();
        let goal = visible.get(self.rng.random_range(0..visible.len().max(1)));
        Ok(goal.map(|&goal| (obs, goal)))
    }

    /// Pushes until a grasp ends the episode: true then, false when told to stop between
    /// actions (`stop` says whether to).
    fn episode(
        &mut self,
        mut obs: Heightmaps,
        goal: ObjectId,
        policy: &Policy,
        shipper: &mut Shipper,
        report: &mut ActorReport,
        stop: &mut dyn FnMut() -> Result<bool>,
    ) -> Result<bool> {
        let episode = self.id.episode(report.episodes);
        for step in 0u32.. {
            let epsilon = self.config.epsilon(self.id.index, report.actions);
            let choice = policy
                .agent
                .decide(&obs, goal, step as usize, epsilon, &mut self.rng)?;
            let pictures_ns = self.pictures(report.episodes, &obs, &choice)?;
            let Choice {
                decision, grasp, ..
            } = choice;
            if let Some(p) = self.unlabelled.take() {
                shipper.ship(p, Some(&decision))?;
            }
            if decision.action.primitive == Primitive::Grasp && self.config.grasp_trials > 0 {
                self.trials(&obs, goal, &grasp, &decision, shipper, report)?;
            }
            let outcome = self.tabletop.act(&decision.action, &obs)?;
            report.actions += 1;
            let transition = Transition {
                episode,
                step,
                goal,
                obs,
                action: decision.action,
                reward: 0.0,
                grasped: outcome.grasped,
                next_value: None,
                next: None,
            };
            obs = self.camera.render(&self.tabletop);
            if decision.action.primitive == Primitive::Push {
                self.unlabelled = Some(Unlabelled {
                    push_changed: Some(detect_change(&transition.obs, &obs, goal)),
                    transition,
                    decision,
                    ends: None,
                    scene_seed: self.scene_seed,
                    pictures_ns,
                });
                // Stop between actions, not only between episodes: a push chain can be long.
                if stop()? {
                    return Ok(false);
                }
                continue;
            }
            self.failures_in_a_row = if outcome.grasped.is_some() {
                0
            } else {
                self.failures_in_a_row + 1
            };
            let origin = shipper.origin;
            let grasp = Unlabelled::grasp(
                transition,
                decision,
                origin,
                false,
                self.scene_seed,
                pictures_ns,
            );
            report.episodes += 1;
            report.goal_grasps += u64::from(grasp.transition.reward > 0.0);
            self.unlabelled = Some(grasp);
            break;
        }
        Ok(true)
    }

    /// The pictures of this step, every `image_every` episodes: when they were logged.
    fn pictures(&self, episodes: u64, obs: &Heightmaps, choice: &Choice) -> Result<Option<u64>> {
        let every = self.config.logging.image_every;
        (every > 0 && episodes.is_multiple_of(every))
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
    /// shipped at once as an episode of its own.
    fn trials(
        &mut self,
        obs: &Heightmaps,
        goal: ObjectId,
        grasp: &QMaps,
        decision: &Decision,
        shipper: &mut Shipper,
        report: &mut ActorReport,
    ) -> Result<()> {
        let trials = trial_grasps(
            obs,
            goal,
            grasp,
            decision,
            self.config.grasp_trials,
            &self.config.policy,
            &mut self.rng,
        )?;
        for trial in trials {
            let outcome = self.tabletop.replica().act(&trial.action, obs)?;
            let transition = Transition {
                episode: self.id.trial(report.trials),
                step: 0,
                goal,
                obs: obs.clone(),
                action: trial.action,
                reward: 0.0,
                grasped: outcome.grasped,
                next_value: None,
                next: None,
            };
            report.trials += 1;
            let unlabelled = Unlabelled::grasp(
                transition,
                trial,
                shipper.origin,
                true,
                self.scene_seed,
                None,
            );
            // A successful trial bootstraps on the executed grasp's view of this scene (its
            // goal grasp Q), standing in for the scene it would leave.
            shipper.ship(unlabelled, Some(decision))?;
        }
        Ok(())
    }
}
