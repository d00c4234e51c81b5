//! Steps on their way to the buffer: a step waits ([`Unlabelled`]) until the next decision in
//! its scene gives its label's next value (and a push's reward the goal's grasp Q after it),
//! then travels with its actor's initial priority on its environment's [`Stream`]
//! ([`Shipper`]), logged as it goes.

use anyhow::Result;
use experience::Transition;
use mcaplog::RunLog;
use policy::{Decision, PushReward, grasp_label, grasp_reward, push_label};
use sim::Primitive;
use wire::{EpisodeEnd, Message, Origin, Outbox, Step};

use super::heartbeat::Heartbeat;
use rundir::config::RunConfig;
use rundir::record::{ACTOR_EPISODE, ACTOR_STEP, EpisodeRecord, StepRecord};

/// A step waiting for the next decision.
pub(super) struct Unlabelled {
    pub(super) transition: Transition,
    pub(super) decision: Decision,
    /// For a push: its reward needs the goal's grasp Q after it; the change around the goal
    /// is known at once.
    pub(super) push_changed: Option<sim::measure::ChangeReport>,
    /// For a grasp: the episode it ends.
    pub(super) ends: Option<EpisodeEnd>,
    /// The scene the episode played on.
    pub(super) scene_seed: u64,
    /// When the pictures of this step were logged, if they were.
    pub(super) pictures_ns: Option<u64>,
    /// The weights its decision was made with.
    pub(super) weights_version: u64,
}

/// One environment's messages to the buffer: the origin of the next (its sequence counts
/// every message, so the buffer can prove nothing was lost) and the steps it sent.
pub(super) struct Stream {
    pub(super) origin: Origin,
    pub(super) steps_sent: u64,
}

/// What every environment of the process ships through: the one publisher of the steps
/// topic, the process's heartbeat (it beats while a send waits), the log and the labels'
/// settings.
pub(super) struct Shipper<'a> {
    log: &'a RunLog,
    outbox: Outbox,
    heartbeat: Heartbeat,
    gamma: f32,
    push_reward: PushReward,
}

impl Unlabelled {
    /// A grasp's step, which ends its episode: scored with the grasp reward.
    pub(super) fn grasp(
        mut transition: Transition,
        decision: Decision,
        trial: bool,
        scene_seed: u64,
        pictures_ns: Option<u64>,
        weights_version: u64,
    ) -> Self {
        transition.reward = grasp_reward(transition.grasped, transition.goal);
        Self {
            ends: Some(episode_end(&transition, trial)),
            transition,
            decision,
            push_changed: None,
            scene_seed,
            pictures_ns,
            weights_version,
        }
    }

    /// This step (a push that lost the goal) as its episode's last, which picked nothing.
    pub(super) fn ending_episode(self) -> Self {
        Self {
            ends: Some(episode_end(&self.transition, false)),
            ..self
        }
    }
}

/// The end of the episode whose last step is `last`.
fn episode_end(last: &Transition, trial: bool) -> EpisodeEnd {
    EpisodeEnd {
        // Stamped when sent.
        origin: Origin {
            actor: 0,
            incarnation: 0,
            seq: 0,
        },
        episode: last.episode,
        goal: last.goal,
        grasped: last.grasped,
        steps: last.step + 1,
        trial,
    }
}

impl Stream {
    pub(super) fn new(origin: Origin) -> Self {
        Self {
            origin,
            steps_sent: 0,
        }
    }

    fn next_origin(&mut self) -> Origin {
        let origin = self.origin;
        self.origin.seq += 1;
        origin
    }
}

impl<'a> Shipper<'a> {
    pub(super) fn new(
        log: &'a RunLog,
        outbox: Outbox,
        heartbeat: Heartbeat,
        config: &RunConfig,
    ) -> Self {
        Self {
            log,
            outbox,
            heartbeat,
            gamma: config.learning.gamma,
            push_reward: config.push_reward,
        }
    }

    pub(super) fn heartbeat(&mut self) -> &mut Heartbeat {
        &mut self.heartbeat
    }

    /// Sends on the steps topic; held back by the buffer, the process is heard meanwhile.
    fn send(&mut self, message: &Message) -> Result<()> {
        let heartbeat = &mut self.heartbeat;
        Ok(self
            .outbox
            .send_waiting(message, &mut || heartbeat.beat())?)
    }

    /// Completes a pending step with the next state's values and sends it (and the end of
    /// its episode) on `stream`. `next`: the next decision in the same scene, `None` if the
    /// scene (or, the goal lost, the episode) ended.
    pub(super) fn ship(
        &mut self,
        stream: &mut Stream,
        mut pending: Unlabelled,
        next: Option<&Decision>,
    ) -> Result<()> {
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
                // Without a next decision (the push lost the goal) only the change counts.
                let after = next.map_or(before, |d| d.goal_grasp_q);
                t.reward = self.push_reward.reward(before, after, change);
                let next_value = next.map(|d| d.state_value());
                (push_label(t.reward, next_value, self.gamma), next_value)
            }
        };
        t.next_value = next_value;
        let d = &pending.decision;
        let step = Step {
            origin: stream.next_origin(),
            priority: f64::from((label - d.predicted_q).abs()),
            predicted_q: d.predicted_q,
            explored: d.explored,
            weights_version: pending.weights_version,
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
            weights_version: step.weights_version,
            pictures_ns: pending.pictures_ns,
        };
        self.send(&Message::Step(step))?;
        stream.steps_sent += 1;
        self.log.json(ACTOR_STEP, &record)?;
        if let Some(mut end) = pending.ends {
            end.origin = stream.next_origin();
            self.send(&Message::EpisodeEnd(end.clone()))?;
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
