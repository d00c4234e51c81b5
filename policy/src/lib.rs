//! The policy side of pushgrasp: what an actor does between the simulator and the networks.
//!
//! Q maps reach this crate as plain `f32` arrays ([`QMaps`]), so it has no neural-network
//! dependency: the actor turns an observation and the push and grasp Q maps into an action
//! with the paper's hierarchical rule (grasp once the goal's grasp Q exceeds Q*, else push, at
//! most five pushes) under epsilon-greedy exploration, and scores what happened with the
//! paper's grasp and push rewards, and turns a step's reward and next value into the label
//! the learner trains towards.

pub mod config;
pub mod error;
pub mod goal_guard;
pub mod grasp_repeats;
pub mod grasp_squeeze;
pub mod grasp_view_edge;
pub mod jaws_landing;
pub mod label;
pub mod policy;
pub mod push_reach;
pub mod push_retreat;
pub mod push_sweep;
pub mod qmaps;
pub mod regions;
pub mod reward;

pub use config::{PolicyConfig, Rule};
pub use error::PolicyError;
pub use goal_guard::pushes_keeping_goal;
pub use grasp_repeats::{REPEAT_RADIUS, grasps_not_repeating};
pub use grasp_squeeze::grasps_holding_goal;
pub use grasp_view_edge::grasps_across_view_edge;
pub use jaws_landing::{
    grasps_landing_clear, pushes_landing_clear, pushes_landing_clear_of, pushes_landing_clear_of_at,
};
pub use label::{grasp_label, push_label};
pub use policy::{Decision, Mode, PolicyInput, Reason, choose, trial_grasps};
pub use push_reach::pushes_near_goal;
pub use push_retreat::push_start_clear_of_goal;
pub use qmaps::QMaps;
pub use regions::{
    PUSH_START_MAX_HEIGHT, grasp_choices, grasp_region, push_region, valid_push_starts,
};
pub use reward::{GRASP_REWARD, PUSH_REWARD, PushReward, Q_IMPROVEMENT, grasp_reward, push_reward};
