//! The paper's rewards: a grasp earns 1 only for the goal object; a push earns +0.5 when it
//! made the goal more graspable and changed its surroundings, -0.5 when it changed nothing.
//! The baselines and ablations swap the push reward ([`PushReward`]).

use serde::{Deserialize, Serialize};
use sim::ObjectId;
use sim::measure::ChangeReport;

/// Reward of a push that raised the goal's grasp Q enough and changed its surroundings; its
/// negation is the reward of a push that changed nothing around the goal.
pub const PUSH_REWARD: f32 = 0.5;

/// How much a push must raise the goal's grasp Q (the highest grasp Q inside the goal mask)
/// to earn [`PUSH_REWARD`]; strictly more than this.
pub const Q_IMPROVEMENT: f32 = 0.1;

/// Reward of a grasp that picked the goal object.
pub const GRASP_REWARD: f32 = 1.0;

/// Grasp reward R_g: [`GRASP_REWARD`] if the goal object itself was grasped, else 0. Grasping another
/// object earns nothing here; goal relabelling turns it into a success for that object.
pub fn grasp_reward(grasped: Option<ObjectId>, goal: ObjectId) -> f32 {
    if grasped == Some(goal) {
        GRASP_REWARD
    } else {
        0.0
    }
}

/// Which reward a push earns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PushReward {
    /// The paper's: the grasp net judges the push ([`push_reward`]).
    #[default]
    Dense,
    /// VPG's: +0.5 whenever the goal's surroundings changed, else 0.
    Change,
    /// No push reward at all (the ablation "without dense reward"): a push is worth only
    /// what it leads to, through its bootstrapped label.
    None,
}

impl PushReward {
    /// The reward of a push, from the goal's grasp Q before and after it and the change
    /// detected around the goal.
    pub fn reward(
        self,
        goal_grasp_q_before: f32,
        goal_grasp_q_after: f32,
        change: &ChangeReport,
    ) -> f32 {
        match self {
            PushReward::Dense => push_reward(goal_grasp_q_before, goal_grasp_q_after, change),
            PushReward::Change => Self::change_reward(change),
            PushReward::None => 0.0,
        }
    }

    /// The reward of a push relabelled to the object the episode grasped instead of its
    /// goal. The grasp-Q improvement for that object is unknown to the buffer, so the
    /// paper's premise that the sequence helped grasp it stands in: the dense reward is +0.5
    /// when the object's surroundings changed and -0.5 when they did not.
    pub fn relabelled(self, change: &ChangeReport) -> f32 {
        match self {
            PushReward::Dense if !change.detected => -PUSH_REWARD,
            PushReward::Dense | PushReward::Change => Self::change_reward(change),
            PushReward::None => 0.0,
        }
    }

    fn change_reward(change: &ChangeReport) -> f32 {
        if change.detected { PUSH_REWARD } else { 0.0 }
    }
}

/// Push reward R_p from the goal's grasp Q before and after the push and change detection
/// around the goal: +0.5 if the grasp Q rose by more than 0.1 and a change was detected,
/// -0.5 if no change was detected, 0 otherwise (a change that did not help the grasp).
pub fn push_reward(
    goal_grasp_q_before: f32,
    goal_grasp_q_after: f32,
    change: &ChangeReport,
) -> f32 {
    if !change.detected {
        -PUSH_REWARD
    } else if goal_grasp_q_after - goal_grasp_q_before > Q_IMPROVEMENT {
        PUSH_REWARD
    } else {
        0.0
    }
}
