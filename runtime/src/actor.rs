//! The actor role: episodes with the newest weights it has received. Observe, Q maps, the
//! hierarchical Q* choice under epsilon-greedy exploration, act in `sim`, reward, ship.
//!
//! A step is shipped once the next decision is made, because its label needs the next
//! state's value and a push's reward needs the goal's grasp Q after it: so a step travels
//! with everything the learner needs and its actor's initial priority. An episode ends with
//! its grasp; its end follows that grasp's step on the same topic.

use agent::{Agent, Choice};
use anyhow::{Context, Result};
use experience::Transition;
use mcaplog::RunLog;
use policy::{Decision, PushReward, QMaps, grasp_reward, trial_grasps};
use policy::{grasp_label, push_label};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::measure::detect_change;
use sim::{Camera, Heightmaps, Primitive, Tabletop};
use wire::{
    EpisodeEnd, Inbox, Message, Origin, Outbox, Role, Status, Step, Topic, Transport, Weights,
};

use super::config::RunConfig;
use super::record::{
    ACTOR_COLOUR, ACTOR_EPISODE, ACTOR_GRASP_Q, ACTOR_HEIGHT, ACTOR_PUSH_Q, ACTOR_SCENE,
    ACTOR_STEP, EpisodeRecord, StepRecord,
};
use super::{Lifeline, stop_requested};

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
}

/// A step waiting for the next decision.
struct Pending {
    transition: Transition,
    decision: Decision,
    /// For a push: its reward needs the goal's grasp Q after it; the change around the goal
    /// is known at once.
    push_changed: Option<sim::measure::ChangeReport>,
    /// For a grasp: the episode it ends.
    ends: Option<EpisodeEnd>,
    /// The scene the episode played on.
    scene_seed: u64,
    /// When the pictures of this step were logged, if they were.
    pictures_ns: Option<u64>,
}

struct Shipper<'a> {
    log: &'a RunLog,
    outbox: Outbox,
    origin: Origin,
    gamma: f32,
    push_reward: PushReward,
    weights_version: u64,
    steps_sent: u64,
}

impl Pending {
    /// A grasp's step, which ends its episode: scored with the grasp reward.
    fn grasp(
        mut transition: Transition,
        decision: Decision,
        origin: Origin,
        trial: bool,
        scene_seed: u64,
        pictures_ns: Option<u64>,
    ) -> Self {
        transition.reward = grasp_reward(transition.grasped, transition.goal);
        Self {
            ends: Some(EpisodeEnd {
                // Stamped when sent.
                origin,
                episode: transition.episode,
                goal: transition.goal,
                grasped: transition.grasped,
                steps: transition.step + 1,
                trial,
            }),
            transition,
            decision,
            push_changed: None,
            scene_seed,
            pictures_ns,
        }
    }
}

impl Shipper<'_> {
    fn next_origin(&mut self) -> Origin {
        let origin = self.origin;
        self.origin.seq += 1;
        origin
    }

    /// Completes a pending step with the next state's values and sends it (and the end of
    /// its episode). `next`: the next decision in the same scene, `None` if the scene ended.
    fn ship(&mut self, mut pending: Pending, next: Option<&Decision>) -> Result<()> {
        let t = &mut pending.transition;
        let (label, next_value) = match t.action.primitive {
            Primitive::Grasp => {
                let next_value = next.map(|d| d.goal_grasp_q);
                let succeeded = t.goal_grasped();
                (
                    grasp_label(t.reward, succeeded, next_value, self.gamma),
                    next_value,
                )
            }
            Primitive::Push => {
                let change = pending
                    .push_changed
                    .as_ref()
                    .expect("pushes carry a change");
                let before = pending.decision.goal_grasp_q;
                // Not reached without a next decision (episodes end with a grasp); then only
                // the change counts.
                let after = next.map_or(before, |d| d.goal_grasp_q);
                t.reward = self.push_reward.reward(before, after, change);
                let next_value = next.map(|d| d.state_value());
                (push_label(t.reward, next_value, self.gamma), next_value)
            }
        };
        t.next_value = next_value;
        let d = &pending.decision;
        let step = Step {
            origin: self.next_origin(),
            priority: f64::from((label - d.predicted_q).abs()),
            predicted_q: d.predicted_q,
            explored: d.explored,
            weights_version: self.weights_version,
            transition: pending.transition,
        };
        let t = &step.transition;
        let record = StepRecord {
            actor: step.origin.actor,
            incarnation: step.origin.incarnation,
            episode: t.episode,
            step: t.step,
            goal: t.goal,
            primitive: format!("{:?}", t.action.primitive).to_lowercase(),
            rotation: t.action.rotation,
            angle_deg: t.action.angle().to_degrees(),
            row: t.action.row,
            col: t.action.col,
            predicted_q: d.predicted_q,
            goal_grasp_q: d.goal_grasp_q,
            explored: d.explored,
            reason: format!("{:?}", d.reason),
            reward: t.reward,
            grasped: t.grasped,
            priority: step.priority,
            weights_version: self.weights_version,
            pictures_ns: pending.pictures_ns,
        };
        self.outbox.send(&Message::Step(step))?;
        self.steps_sent += 1;
        self.log.json(ACTOR_STEP, &record)?;
        if let Some(mut end) = pending.ends {
            end.origin = self.next_origin();
            self.outbox.send(&Message::EpisodeEnd(end.clone()))?;
            if end.trial {
                return Ok(());
            }
            self.log.json(
                ACTOR_EPISODE,
                &EpisodeRecord {
                    actor: end.origin.actor,
                    incarnation: end.origin.incarnation,
                    episode: end.episode,
                    scene_seed: pending.scene_seed,
                    goal: end.goal,
                    grasped: end.grasped,
                    goal_grasped: end.goal_grasped(),
                    steps: end.steps,
                },
            )?;
        }
        Ok(())
    }
}

/// The actor's agent and where new weights come from.
struct Policy {
    agent: Agent,
    weights: Inbox,
    version: u64,
}

impl Policy {
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
    let mut shipper = Shipper {
        log,
        outbox: Outbox::open(transport, Topic::Steps)?,
        origin: Origin {
            actor: id.index,
            incarnation: id.incarnation,
            seq: 0,
        },
        gamma: config.learning.gamma,
        push_reward: config.push_reward,
        weights_version: 0,
        steps_sent: 0,
    };
    let mut policy = Policy {
        agent: Agent::new(
            &config.net,
            config.side(),
            config.policy.clone(),
            config.mode(),
        ),
        weights: Inbox::open(transport, Topic::Weights)?,
        version: 0,
    };
    let mut report = ActorReport {
        actor: id.index,
        incarnation: id.incarnation,
        ..ActorReport::default()
    };
    // Nothing to act with until the learner's first weights arrive.
    if !policy.refresh(true, lifeline, &mut control)? {
        return Ok(report);
    }

    let acting = std::time::Instant::now();
    let seed = id.seed(config.seed);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut scene_seed = seed;
    let new_scene = |seed, rng: &mut ChaCha8Rng| {
        Tabletop::random_with_rows(&config.sim, config.objects, config.rows.draw(rng), seed)
    };
    let (mut tabletop, _) = new_scene(scene_seed, &mut rng)?;
    let camera = Camera::new(tabletop.grid());
    let mut pending: Option<Pending> = None;
    let mut failures_in_a_row = 0;

    'episodes: while !lifeline.lost() && !stop_requested(&mut control, Role::Actor)? {
        policy.refresh(false, lifeline, &mut control)?;
        shipper.weights_version = policy.version;

        // A new scene when this one is cleared or stuck; a waiting step then ends the chain.
        let mut obs = camera.render(&tabletop);
        if obs.visible_ids().is_empty() || failures_in_a_row >= config.max_failures_per_scene {
            if let Some(p) = pending.take() {
                shipper.ship(p, None)?;
            }
            scene_seed = scene_seed.wrapping_add(1);
            tabletop = new_scene(scene_seed, &mut rng)?.0;
            obs = camera.render(&tabletop);
            failures_in_a_row = 0;
        }
        let visible = obs.visible_ids();
        let Some(&goal) = visible.get(rng.random_range(0..visible.len().max(1))) else {
            continue;
        };
        let episode = id.episode(report.episodes);
        let mut step = 0u32;
        loop {
            let epsilon = config.epsilon(id.index, report.actions);
            let Choice {
                decision,
                grasp,
                push,
            } = policy
                .agent
                .decide(&obs, goal, step as usize, epsilon, &mut rng)?;
            let every = config.logging.image_every;
            let pictures_ns = (every > 0 && report.episodes.is_multiple_of(every))
                .then(|| log_pictures(log, &tabletop, &obs, &grasp, push.as_ref()))
                .transpose()?;
            if let Some(p) = pending.take() {
                shipper.ship(p, Some(&decision))?;
            }
            if decision.action.primitive == Primitive::Grasp && config.grasp_trials > 0 {
                let trials = trial_grasps(
                    &obs,
                    goal,
                    &grasp,
                    &decision,
                    config.grasp_trials,
                    &config.policy,
                    &mut rng,
                )?;
                for trial in trials {
                    let outcome = tabletop.replica().act(&trial.action, &obs)?;
                    let transition = Transition {
                        episode: id.trial(report.trials),
                        step: 0,
                        goal,
                        obs: obs.clone(),
                        action: trial.action,
                        reward: 0.0,
                        grasped: outcome.grasped,
                        next_value: None,
                    };
                    report.trials += 1;
                    let pending =
                        Pending::grasp(transition, trial, shipper.origin, true, scene_seed, None);
                    // A successful trial bootstraps on the executed grasp's view of this
                    // scene (its goal grasp Q), standing in for the scene it would leave.
                    shipper.ship(pending, Some(&decision))?;
                }
            }
            let outcome = tabletop.act(&decision.action, &obs)?;
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
            };
            step += 1;
            obs = camera.render(&tabletop);
            if decision.action.primitive == Primitive::Push {
                pending = Some(Pending {
                    push_changed: Some(detect_change(&transition.obs, &obs, goal)),
                    transition,
                    decision,
                    ends: None,
                    scene_seed,
                    pictures_ns,
                });
                // Stop between actions, not only between episodes: a push chain can be long.
                if lifeline.lost() || stop_requested(&mut control, Role::Actor)? {
                    break 'episodes;
                }
                continue;
            }
            failures_in_a_row = if outcome.grasped.is_some() {
                0
            } else {
                failures_in_a_row + 1
            };
            let grasp = Pending::grasp(
                transition,
                decision,
                shipper.origin,
                false,
                scene_seed,
                pictures_ns,
            );
            let goal_grasped = grasp.transition.reward > 0.0;
            pending = Some(grasp);
            report.episodes += 1;
            report.goal_grasps += u64::from(goal_grasped);
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
    report.acting_s = acting.elapsed().as_secs_f64();
    Ok(report)
}

/// What the actor saw and the scene it acted on, all at one time, which is returned: colour,
/// height (tenths of a millimetre) and the best grasp and push Q over the rotations
/// (hundredths, so 0..2.55) as images Foxglove shows as they are, and the objects as boxes.
fn log_pictures(
    log: &RunLog,
    tabletop: &Tabletop,
    obs: &Heightmaps,
    grasp: &QMaps,
    push: Option<&QMaps>,
) -> Result<u64> {
    let t = mcaplog::now_ns();
    if !log.enabled() {
        return Ok(t);
    }
    let side = obs.side() as u32;
    let colour: Vec<u8> = obs.colour.iter().flatten().copied().collect();
    let height: Vec<u8> = obs
        .height
        .iter()
        .flat_map(|h| ((h * 1e4).round().clamp(0.0, 65535.0) as u16).to_le_bytes())
        .collect();
    log.raw_image(ACTOR_COLOUR, t, side, side, "rgb8", &colour)?;
    log.raw_image(ACTOR_HEIGHT, t, side, side, "mono16", &height)?;
    log.raw_image(ACTOR_GRASP_Q, t, side, side, "mono8", &best_q(grasp))?;
    if let Some(push) = push {
        log.raw_image(ACTOR_PUSH_Q, t, side, side, "mono8", &best_q(push))?;
    }
    log.scene_update(ACTOR_SCENE, t, &scene(tabletop, t))?;
    Ok(t)
}

/// The best Q over the rotations per pixel, in hundredths.
fn best_q(maps: &QMaps) -> Vec<u8> {
    let side = maps.side();
    (0..side * side)
        .map(|i| {
            let best = (0..maps.rotations())
                .map(|k| maps.get(k, i / side, i % side))
                .fold(f32::NEG_INFINITY, f32::max);
            (best * 100.0).round().clamp(0.0, 255.0) as u8
        })
        .collect()
}

/// The objects on the table as boxes in the world frame, one entity per object id.
fn scene(tabletop: &Tabletop, time_ns: u64) -> mcaplog::SceneUpdate {
    let vector = |v: sim::rapier3d::prelude::Vector| mcaplog::Vector3 {
        x: f64::from(v.x),
        y: f64::from(v.y),
        z: f64::from(v.z),
    };
    let entities = tabletop
        .objects()
        .map(|object| {
            let (lo, hi) = object.kind.bounds();
            let q = object.pose.rotation;
            let [r, g, b] = object.colour.map(|c| f64::from(c) / 255.0);
            mcaplog::SceneEntity {
                timestamp: Some(mcaplog::timestamp(time_ns)),
                frame_id: "world".into(),
                id: format!("object-{}", object.id),
                lifetime: None,
                frame_locked: false,
                cubes: vec![mcaplog::CubePrimitive {
                    pose: Some(mcaplog::Pose {
                        position: Some(vector(object.pose.transform_point((lo + hi) / 2.0))),
                        orientation: Some(mcaplog::Quaternion {
                            x: f64::from(q.x),
                            y: f64::from(q.y),
                            z: f64::from(q.z),
                            w: f64::from(q.w),
                        }),
                    }),
                    size: Some(vector(hi - lo)),
                    color: Some(mcaplog::Color { r, g, b, a: 1.0 }),
                }],
            }
        })
        .collect();
    mcaplog::SceneUpdate { entities }
}
