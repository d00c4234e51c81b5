//! The policy's settings: the paper's Q* rule and its push budget, exploration's rate, and
//! the test-time masks (grasp margin, goal guard, landing guard, its finer view and its
//! retreat, push reach, free border, grasp landing guard, squeeze guard, view edge guard),
//! each off or at the paper's value by default, each checked on load.

use std::ops::Bound;

use serde::{Deserialize, Serialize};
use sim::{ConfigError, PixelGrid};

/// The policy's settings; the defaults are the paper's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PolicyConfig {
    /// Q*: grasp once the goal's grasp Q exceeds this (just below the 2.0 a reliable grasp
    /// converges to with gamma = 0.5).
    pub q_star: f32,
    /// Pushes allowed in an episode before the grasp is forced.
    pub max_pushes: usize,
    /// Grasps stay this far (metres) inside the goal's mask, where the mask is wider than
    /// twice this (else they go to its deepest pixels): in clutter, direct grasps on the
    /// goal's rim fail most often (results/archive.md, "Grasps off the goal's rim"). 0:
    /// anywhere on the mask, as the paper.
    pub grasp_margin: f32,
    /// Exploration rate at iteration 0.
    pub epsilon_start: f32,
    /// Exploration rate the decay stops at.
    pub epsilon_end: f32,
    /// Factor the exploration rate shrinks by per action. f64: 0.9998 in f32 is off by 2.6e-8,
    /// which compounds to a relative 2e-4 by the time epsilon reaches its floor.
    pub epsilon_decay: f64,
    /// How push or grasp is chosen in push-grasp mode.
    pub rule: Rule,
    /// Under [`Rule::ThresholdOrCrowded`]: push while more than this share of the ring
    /// around the goal is occupied ([`sim::measure::occupancy_ratio`]; the authors' test:
    /// 0.3).
    pub crowded_border: f32,
    /// Pushes predicted to leave the goal's centre less than this far (metres) inside the
    /// workspace are not chosen ([`crate::pushes_keeping_goal`]): a goal out of the
    /// workspace is lost, and its run with it. `None`: every push start is open, as in the
    /// paper.
    pub goal_guard: Option<f32>,
    /// Pushes whose closed jaws, widened by this margin (metres), would come down on an
    /// object at their start are not chosen ([`crate::pushes_landing_clear`]): the
    /// simulator squeezes what they land on until the fingers throw it. `None`: every push
    /// start is open, as in the paper.
    pub landing_guard: Option<f32>,
    /// The landing guard also closes the pushes whose jaws come down on the goal as seen
    /// this many times finer than the observation in each direction
    /// ([`crate::pushes_landing_clear_of`], on [`PolicyConfig::landing_view`]'s grid; odd, so
    /// that each observation pixel's centre is a fine pixel's): a pixel's height is the
    /// surface at its centre, and the goal's corner can reach under the jaws in a pixel
    /// whose centre is on the table. 1: the observation alone.
    pub landing_subpixels: usize,
    /// Under the landing guard seen finer: a chosen push whose jaws come down on the goal
    /// as the finer view sees it is not closed but started farther back along its own
    /// direction, at the nearest start (at most this far, metres) the push region holds
    /// and the finer view sees clear of the goal ([`crate::push_start_clear_of_goal`]);
    /// as chosen where there is none. `None`: the finer view closes such pushes.
    pub landing_retreat: Option<f32>,
    /// Grasps whose open jaws, widened by this margin (metres), would come down on an
    /// object, the goal's top included, are not chosen ([`crate::grasps_landing_clear`]),
    /// where any grasp of the goal is left: held up on it, the jaws close above the goal.
    /// `None`: every grasp is open, as in the paper.
    pub grasp_landing_guard: Option<f32>,
    /// Grasps whose pads would close on faces of the goal sloping the same way, more
    /// steeply together than twice this friction coefficient holds, are not chosen
    /// ([`crate::grasps_holding_goal`]), where any grasp of the goal is left: the goal
    /// shoots out of the jaws. The pads' friction with an object is 0.355 (0.5 times 0.71,
    /// as Bullet combines them). `None`: every grasp is open, as in the paper.
    pub squeeze_guard: Option<f32>,
    /// Grasps of a goal whose visible mask reaches a side of the workspace, with the jaws
    /// closing more than 45 degrees off that side's normal, are not chosen
    /// ([`crate::grasps_across_view_edge`]), where any grasp of the goal is left: the goal's
    /// hidden part is squeezed across the side, out of view. `false`: every grasp is open,
    /// as in the paper.
    pub view_edge_guard: bool,
    /// Pushes whose swept band passes farther than this (metres) from the goal are neither
    /// chosen nor drawn when exploring ([`crate::pushes_near_goal`]): they cannot change
    /// the goal's surroundings. `None`: every push start is open, as in the paper.
    pub push_reach: Option<f32>,
    /// Under the Q* rules: grasp, whatever the goal's grasp Q, once at most this share of
    /// the goal's border ring is occupied ([`sim::measure::occupancy_ratio`]). A goal with
    /// nothing around it needs no push, and pushing a free goal on is how most goals leave
    /// the scene. `None`: Q* alone decides, as in the paper.
    pub free_border: Option<f32>,
    /// Under `free_border`: once a grasp has picked nothing since the last push
    /// ([`PolicyInput::grasp_failed_since_push`](crate::PolicyInput::grasp_failed_since_push)),
    /// the free border no longer decides and Q* does: a free goal the grasps keep missing
    /// (at the workspace's edge, or lying where the jaws slip off it) is pushed, rather
    /// than grasped again until the run runs out of attempts.
    pub free_border_once: bool,
}

/// How the policy chooses between pushing and grasping.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Rule {
    /// The paper's: grasp once the goal's grasp Q exceeds Q*, else push.
    #[default]
    Threshold,
    /// Goal-conditioned VPG's: the primitive whose best Q is higher (the grasp's inside the
    /// goal mask, the push's over its valid starts, since no push starts on an object).
    HigherQ,
    /// The authors' code at test time on its designed cases (`main.py`, not the paper): push
    /// while the goal's border ring is more than `crowded_border` occupied or its grasp Q is
    /// at most Q* (there 1.5), else grasp.
    ThresholdOrCrowded,
}

impl Default for PolicyConfig {
    fn default() -> Self {
        Self {
            q_star: 1.8,
            max_pushes: 5,
            grasp_margin: 0.0,
            epsilon_start: 0.5,
            epsilon_end: 0.1,
            epsilon_decay: 0.9998,
            rule: Rule::Threshold,
            crowded_border: 0.3,
            goal_guard: None,
            landing_guard: None,
            landing_subpixels: 1,
            landing_retreat: None,
            grasp_landing_guard: None,
            squeeze_guard: None,
            view_edge_guard: false,
            push_reach: None,
            free_border: None,
            free_border_once: false,
        }
    }
}

impl PolicyConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        ConfigError::check_range("q_star", self.q_star, ..)?;
        ConfigError::check_range("grasp_margin", self.grasp_margin, 0.0..)?;
        ConfigError::check_range("crowded_border", self.crowded_border, 0.0..=1.0)?;
        if let Some(margin) = self.goal_guard {
            ConfigError::check_range("goal_guard", margin, 0.0..)?;
        }
        if let Some(margin) = self.landing_guard {
            ConfigError::check_range("landing_guard", margin, 0.0..)?;
        }
        ConfigError::check_range(
            "landing_subpixels",
            self.landing_subpixels as f64,
            1.0..=9.0,
        )?;
        if self.landing_subpixels.is_multiple_of(2) {
            return Err(ConfigError::new(
                "landing_subpixels",
                format!("{} is even: it must be odd", self.landing_subpixels),
            ));
        }
        if let Some(distance) = self.landing_retreat {
            ConfigError::check_range("landing_retreat", distance, 0.0..)?;
            if self.landing_guard.is_none() || self.landing_subpixels == 1 {
                return Err(ConfigError::new(
                    "landing_retreat",
                    "needs the landing guard seen finer (landing_guard set, landing_subpixels \
                     above 1)"
                        .to_string(),
                ));
            }
        }
        if let Some(margin) = self.grasp_landing_guard {
            ConfigError::check_range("grasp_landing_guard", margin, 0.0..)?;
        }
        if let Some(friction) = self.squeeze_guard {
            ConfigError::check_range("squeeze_guard", friction, 0.0..)?;
        }
        if let Some(reach) = self.push_reach {
            ConfigError::check_range("push_reach", reach, 0.0..)?;
        }
        if let Some(free) = self.free_border {
            ConfigError::check_range("free_border", free, 0.0..=1.0)?;
        }
        ConfigError::check_range("epsilon_start", self.epsilon_start, 0.0..=1.0)?;
        ConfigError::check_range("epsilon_end", self.epsilon_end, 0.0..=1.0)?;
        ConfigError::check_range(
            "epsilon_decay",
            self.epsilon_decay,
            (Bound::Excluded(0.0), Bound::Included(1.0)),
        )
    }

    /// The grid a policy on observations of `grid` wants the scene rendered on for its
    /// landing guard, where that is finer than the observation.
    pub fn landing_view(&self, grid: PixelGrid) -> Option<PixelGrid> {
        (self.landing_guard.is_some() && self.landing_subpixels > 1).then(|| {
            grid.finer(self.landing_subpixels)
                .expect("a whole number of finer pixels spans the workspace")
        })
    }

    /// The exploration rate after `iteration` actions: max(start * decay^iteration, end), as
    /// the original's max(0.5 * 0.9998^iteration, 0.1).
    pub fn epsilon(&self, iteration: u64) -> f32 {
        // powf: the exponent does not fit powi's i32.
        let decayed = f64::from(self.epsilon_start) * self.epsilon_decay.powf(iteration as f64);
        decayed.max(f64::from(self.epsilon_end)) as f32
    }
}
