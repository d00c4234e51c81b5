//! The paper's rewards: a grasp earns 1 only for the goal object; a push earns +0.5 when it
//! made the goal more graspable and changed its surroundings, -0.5 when it changed nothing.

use sim::ObjectId;
use sim::measure::ChangeReport;

/// Reward of a push that raised the goal's grasp Q enough and changed its surroundings; its
/// negation is the reward of a push that changed nothing around the goal.
pub const PUSH_REWARD: f32 = 0.5;

/// How much a push must raise the goal's grasp Q (the highest grasp Q inside the goal mask)
/// to earn [`PUSH_REWARD`]; strictly more than this.
pub const Q_IMPROVEMENT: f32 = 0.1;

/// Grasp reward R_g: 1 if the goal object itself was grasped, else 0. Grasping another
/// object earns nothing here; goal relabelling turns it into a success for that object.
pub fn grasp_reward(grasped: Option<ObjectId>, goal: ObjectId) -> f32 {
    if grasped == Some(goal) { 1.0 } else { 0.0 }
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
