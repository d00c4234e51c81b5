//! Learning during a test, as the authors' code does where the paper is silent (`main.py`
//! backpropagates every executed action whether or not it is testing, and reloads the
//! checkpoint's weights at the start of each test run).
//!
//! Each run starts from the checkpoint's nets and a fresh Adam (a checkpoint holds no
//! optimiser state; the authors' optimiser keeps its moments from run to run while its
//! weights are reloaded). Every executed action gets the training label of the
//! checkpoint's stage (`policy::label`, the push reward of the stage's config) and one update
//! of its own net, the other net frozen, when the stage trains that net. The label needs the
//! next decision's values, so, as in the authors' loop, the decision after an action is made
//! on the nets before that action's update: an update first acts one decision later.

use policy::{Decision, PushReward, grasp_label, grasp_reward, push_label};
use qnet::{Geometry, NetInput, QNetConfig, QNets};
use serde::{Deserialize, Serialize};
use sim::measure::detect_change;
use sim::{Action, Heightmaps, ObjectId, Primitive};

use learner::{LearnerError, LearningConfig, Sample, TrainedNet, Trainer};

/// How a test run learns: the checkpoint's stage settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TestLearning {
    /// The nets' shape (the trainer's geometry).
    pub net: QNetConfig,
    /// The stage's learning rule (its step size, Adam's settings, gamma); its Polyak average
    /// and target nets are not used: the run acts with the nets it trains.
    pub learning: LearningConfig,
    /// The nets the stage trains: an action of another primitive teaches nothing.
    pub trained: Vec<TrainedNet>,
    /// The stage's push reward.
    pub push_reward: PushReward,
}

/// One run's learner: a trainer restored from the checkpoint, and the action waiting for
/// the next decision to be labelled.
pub(crate) struct RunLearner<'a> {
    settings: &'a TestLearning,
    trainer: Trainer,
    waiting: Option<Executed>,
}

/// An executed action and what its label needs.
struct Executed {
    obs: Heightmaps,
    goal: ObjectId,
    decision: Decision,
    grasped: Option<ObjectId>,
}

impl<'a> RunLearner<'a> {
    /// A learner that starts from `nets` (the checkpoint's), for `geometry`'s heightmaps.
    pub(crate) fn start(settings: &'a TestLearning, nets: &QNets, geometry: &Geometry) -> Self {
        let learning = LearningConfig {
            polyak_rate: 1.0,
            target_update_every: 0,
            ..settings.learning.clone()
        };
        let first = settings
            .trained
            .first()
            .copied()
            .unwrap_or(TrainedNet::Grasp);
        let trainer = Trainer::new(
            nets.clone(),
            &settings.net,
            geometry.side(),
            &learning,
            first,
            &nets.device(),
        );
        Self {
            settings,
            trainer,
            waiting: None,
        }
    }

    /// `decision` was executed on `obs` and grasped `grasped`: it waits for the next
    /// decision to be labelled.
    pub(crate) fn executed(
        &mut self,
        obs: &Heightmaps,
        goal: ObjectId,
        decision: Decision,
        grasped: Option<ObjectId>,
    ) {
        self.waiting = Some(Executed {
            obs: obs.clone(),
            goal,
            decision,
            grasped,
        });
    }

    /// Labels the waiting action with `next` (the decision made on `obs`, the scene after
    /// it) and takes its update. Returns the nets to act with from now on, if they changed.
    pub(crate) fn learn(
        &mut self,
        obs: &Heightmaps,
        next: &Decision,
    ) -> Result<Option<QNets>, LearnerError> {
        let Some(executed) = self.waiting.take() else {
            return Ok(None);
        };
        let Executed {
            obs: before,
            goal,
            decision,
            grasped,
        } = executed;
        let Action { primitive, .. } = decision.action;
        let Some(&net) = self
            .settings
            .trained
            .iter()
            .find(|n| n.primitive() == primitive)
        else {
            return Ok(None);
        };
        let gamma = self.settings.learning.gamma;
        let label = match primitive {
            Primitive::Grasp => {
                let reward = grasp_reward(grasped, goal);
                grasp_label(
                    reward,
                    grasped == Some(goal),
                    Some(next.goal_grasp_q),
                    gamma,
                )
            }
            Primitive::Push => {
                let change = detect_change(&before, obs, goal);
                let reward = self.settings.push_reward.reward(
                    decision.goal_grasp_q,
                    next.goal_grasp_q,
                    &change,
                );
                push_label(reward, Some(next.state_value()), gamma)
            }
        };
        let sample = Sample {
            input: NetInput::encode(&before, goal),
            action: decision.action,
            label,
            weight: 1.0,
            succeeded: primitive == Primitive::Grasp && grasped == Some(goal),
        };
        if self.trainer.trained() != net {
            self.trainer.set_trained(net);
        }
        self.trainer.train_step(&[sample])?;
        Ok(Some(self.trainer.published_nets()))
    }

    /// Updates taken in this run (its trainer starts from none).
    pub(crate) fn updates(&self) -> usize {
        self.trainer.updates() as usize
    }
}
