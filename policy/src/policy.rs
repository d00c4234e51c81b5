//! The hierarchical push-grasp policy: the grasp net is the discriminator (grasp once the
//! goal's grasp Q exceeds Q*), the push net acts below it (at most five pushes, then a
//! grasp), and epsilon-greedy exploration draws the chosen primitive's pixel and rotation.
//! The goal-conditioned VPG baseline swaps the discriminator for VPG's rule, and the
//! authors' test-time rule adds a crowded-border test to it ([`Rule`]).
//!
//! The rule that chooses and the masks it chooses within (grasp region, push starts, trial grasps)
//! are one policy, read together against the paper.

use std::ops::Bound;

use rand::{Rng, RngExt};
use serde::{Deserialize, Serialize};
use sim::measure::occupancy_ratio;
use sim::{Action, ConfigError, Heightmaps, ObjectId, Primitive, ROTATIONS};

use crate::error::PolicyError;
use crate::goal_guard::pushes_keeping_goal;
use crate::grasp_repeats::grasps_not_repeating;
use crate::push_landing::pushes_landing_clear;
use crate::push_reach::pushes_near_goal;
use crate::qmaps::QMaps;

/// A push may only start where the surface is lower than this (metres): "pushes may not
/// start on top of an object during training". Every block rests at least 2.5 cm tall, so
/// only the sloped or rounded fringe of an object can be lower.
pub const PUSH_START_MAX_HEIGHT: f32 = 0.01;

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
    /// around the goal is occupied ([`occupancy_ratio`]; the authors' test: 0.3).
    pub crowded_border: f32,
    /// Pushes predicted to leave the goal's centre less than this far (metres) inside the
    /// workspace are not chosen ([`pushes_keeping_goal`]): a goal out of the workspace is
    /// lost, and its run with it. `None`: every push start is open, as in the paper.
    pub goal_guard: Option<f32>,
    /// Pushes whose closed jaws, widened by this margin (metres), would come down on an
    /// object at their start are not chosen ([`pushes_landing_clear`]): the simulator
    /// squeezes what they land on until the fingers throw it. `None`: every push start is
    /// open, as in the paper.
    pub landing_guard: Option<f32>,
    /// Pushes whose swept band passes farther than this (metres) from the goal are neither
    /// chosen nor drawn when exploring ([`pushes_near_goal`]): they cannot change the goal's
    /// surroundings. `None`: every push start is open, as in the paper.
    pub push_reach: Option<f32>,
    /// Under the Q* rules: grasp, whatever the goal's grasp Q, once at most this share of
    /// the goal's border ring is occupied ([`occupancy_ratio`]). A goal with nothing around
    /// it needs no push, and pushing a free goal on is how most goals leave the scene.
    /// `None`: Q* alone decides, as in the paper.
    pub free_border: Option<f32>,
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
            push_reach: None,
            free_border: None,
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

    /// The exploration rate after `iteration` actions: max(start * decay^iteration, end), as
    /// the original's max(0.5 * 0.9998^iteration, 0.1).
    pub fn epsilon(&self, iteration: u64) -> f32 {
        // powf: the exponent does not fit powi's i32.
        let decayed = f64::from(self.epsilon_start) * self.epsilon_decay.powf(iteration as f64);
        decayed.max(f64::from(self.epsilon_end)) as f32
    }
}

/// Which primitives the policy may use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// Stage 1 (goal-conditioned grasping): every action is a grasp.
    GraspOnly,
    /// Stages 2 and 3 and testing: push until the goal is graspable, then grasp.
    PushGrasp,
}

/// Why the policy picked its primitive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Reason {
    /// Grasp: the mode allows nothing else.
    GraspOnlyMode,
    /// Grasp: the goal's grasp Q exceeds Q*.
    AboveThreshold,
    /// Grasp: the episode's pushes are used up.
    PushBudgetSpent,
    /// Grasp: no push Q maps were given.
    NoPushMaps,
    /// Push: the goal's grasp Q is at most Q*.
    BelowThreshold,
    /// Push ([`Rule::ThresholdOrCrowded`]): the goal's grasp Q exceeds Q*, but its border
    /// ring is more occupied than `crowded_border`.
    BorderCrowded,
    /// Grasp: the goal's grasp Q is at most Q*, but its border ring is at most
    /// `free_border` occupied.
    BorderFree,
    /// Grasp (VPG's rule): the goal's grasp Q is at least the best push Q.
    GraspQHigher,
    /// Push (VPG's rule): the best push Q is higher than the goal's grasp Q.
    PushQHigher,
    /// Grasp, tried on a copy of the scene beside the one executed ([`trial_grasps`]).
    Trial,
}

/// What the policy sees at one step.
#[derive(Clone, Copy, Debug)]
pub struct PolicyInput<'a> {
    /// The observation the Q maps were computed on.
    pub obs: &'a Heightmaps,
    /// The episode's goal object.
    pub goal: ObjectId,
    /// Grasp Q maps for this observation and goal.
    pub grasp: &'a QMaps,
    /// Push Q maps, if the push net is in use.
    pub push: Option<&'a QMaps>,
    /// Pushes already made in this episode.
    pub pushes_so_far: usize,
    /// How far a push moves the tool (metres; the simulator's `push_length`).
    pub push_length: f32,
    /// Grasps that picked nothing, remembered by the caller (the test loop under `eval
    /// --avoid-failed-grasps`; empty otherwise): none is chosen again, nor a grasp near it
    /// ([`REPEAT_RADIUS`](crate::REPEAT_RADIUS)).
    pub failed_grasps: &'a [Action],
}

/// The policy's choice and what it was based on.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Decision {
    /// The action to execute.
    pub action: Action,
    /// The Q value of the executed primitive at the executed rotation and pixel (explored or
    /// not): the value the loss compares with the label.
    pub predicted_q: f32,
    /// The highest grasp Q over all rotations inside the grasp region (the goal mask when
    /// the goal is visible): the discriminator's score, and the "before" of a push reward.
    pub goal_grasp_q: f32,
    /// The highest push Q over the pushes the policy may choose ([`push_region`]), when push
    /// maps were given.
    pub best_push_q: Option<f32>,
    /// Whether the pixel and rotation were drawn at random rather than the argmax.
    pub explored: bool,
    /// Why this primitive.
    pub reason: Reason,
    /// Whether the goal was seen from above; when not, the grasp region was every object.
    pub goal_visible: bool,
}

impl Decision {
    /// What the state this decision was made in is worth to the step before it: the goal's
    /// grasp Q when a grasp comes next, the best push Q when a push does.
    pub fn state_value(&self) -> f32 {
        match self.action.primitive {
            Primitive::Grasp => self.goal_grasp_q,
            Primitive::Push => self.best_push_q.unwrap_or(self.goal_grasp_q),
        }
    }
}

/// Where a grasp may go and where the goal's grasp Q is read: the goal mask less its rim
/// `margin` metres wide (its deepest pixels where the rim would take all of it); if the goal
/// is hidden, every object pixel (so the policy can uncover it by grasping what lies on
/// top); if the table is bare, everywhere. Row-major, `side * side`.
pub fn grasp_region(obs: &Heightmaps, goal: ObjectId, margin: f32) -> Vec<bool> {
    let mask = obs.goal_mask(goal);
    if mask.contains(&true) {
        let rim = (margin / obs.grid.pixel_size()).round() as u32;
        return without_rim(&mask, obs.side(), rim);
    }
    let objects: Vec<bool> = obs.ids.iter().map(|&id| id != 0).collect();
    if objects.contains(&true) {
        return objects;
    }
    vec![true; obs.ids.len()]
}

/// The pixels of `mask` more than `rim` steps (in any of 8 directions) from a pixel outside
/// it or from the map's border; where there are none, its deepest pixels.
fn without_rim(mask: &[bool], side: usize, rim: u32) -> Vec<bool> {
    if rim == 0 {
        return mask.to_vec();
    }
    let depth = chessboard_depth(mask, side);
    let keep = (rim + 1).min(depth.iter().copied().max().unwrap_or(0));
    depth.iter().map(|&d| d > 0 && d >= keep).collect()
}

/// Each pixel's chessboard distance to the nearest pixel outside `mask` (the map's border
/// counts as outside): 0 outside, 1 on the rim. Two raster passes.
fn chessboard_depth(mask: &[bool], side: usize) -> Vec<u32> {
    let mut depth: Vec<u32> = mask.iter().map(|&m| if m { u32::MAX } else { 0 }).collect();
    let at = |depth: &[u32], r: isize, c: isize| -> u32 {
        if r < 0 || c < 0 || r >= side as isize || c >= side as isize {
            0
        } else {
            depth[r as usize * side + c as usize]
        }
    };
    let mut pass = |order: &mut dyn Iterator<Item = usize>, neighbours: [(isize, isize); 4]| {
        for i in order {
            if depth[i] == 0 {
                continue;
            }
            let (r, c) = ((i / side) as isize, (i % side) as isize);
            let nearest = neighbours
                .iter()
                .map(|&(dr, dc)| at(&depth, r + dr, c + dc))
                .min()
                .expect("four neighbours");
            depth[i] = depth[i].min(nearest.saturating_add(1));
        }
    };
    pass(&mut (0..mask.len()), [(-1, -1), (-1, 0), (-1, 1), (0, -1)]);
    pass(
        &mut (0..mask.len()).rev(),
        [(1, 1), (1, 0), (1, -1), (0, 1)],
    );
    depth
}

/// Where a push may start: pixels lower than [`PUSH_START_MAX_HEIGHT`], i.e. not on top of
/// an object; everywhere if the objects cover every pixel. Row-major, `side * side`.
pub fn valid_push_starts(obs: &Heightmaps) -> Vec<bool> {
    let starts: Vec<bool> = obs
        .height
        .iter()
        .map(|&h| h < PUSH_START_MAX_HEIGHT)
        .collect();
    if starts.contains(&true) {
        starts
    } else {
        vec![true; starts.len()]
    }
}

/// Where a push may go, laid out as [`QMaps::best_where`] reads it: the
/// [`valid_push_starts`] for every rotation; under the config's `goal_guard`, per rotation,
/// those of them that keep the goal in the workspace ([`pushes_keeping_goal`]); under its
/// `push_reach`, of those, the ones that pass near the goal ([`pushes_near_goal`]); under
/// its `landing_guard`, of those, the ones whose jaws come down clear of every object
/// ([`pushes_landing_clear`]). A mask that would leave no push is not applied, nor any
/// after it: the landing guard comes last so that, where it would close every push near a
/// goal packed in on all sides, the pushes that reach the goal stay open rather than
/// pushes in the air, which change nothing.
pub fn push_region(
    obs: &Heightmaps,
    goal: ObjectId,
    config: &PolicyConfig,
    push_length: f32,
) -> Vec<bool> {
    let starts = valid_push_starts(obs);
    let masks: Vec<Vec<bool>> = [
        config
            .goal_guard
            .map(|margin| pushes_keeping_goal(obs, goal, push_length, margin)),
        config
            .push_reach
            .map(|reach| pushes_near_goal(obs, goal, push_length, reach)),
        config
            .landing_guard
            .map(|margin| pushes_landing_clear(obs, margin)),
    ]
    .into_iter()
    .flatten()
    .collect();
    if masks.is_empty() {
        return starts;
    }
    let mut region = starts.repeat(ROTATIONS as usize);
    for mask in masks {
        let narrowed: Vec<bool> = region.iter().zip(&mask).map(|(&r, &m)| r && m).collect();
        if !narrowed.contains(&true) {
            break;
        }
        region = narrowed;
    }
    region
}

/// Picks the next action. Grasp when `mode` is grasp-only, the push budget is spent, or
/// there are no push maps; otherwise the config's [`Rule`] decides (the paper's: grasp when
/// the goal's grasp Q exceeds Q*, else push; under `free_border`, also grasp when the goal's
/// border ring is free). The primitive goes to the argmax of its Q maps
/// over its allowed pixels ([`grasp_region`], [`push_region`]) and all rotations, or,
/// with probability `epsilon`, to a pixel and rotation drawn uniformly from the same set.
/// Deterministic given `rng`.
///
/// Errors if a Q map's shape does not match the observation and [`ROTATIONS`], if a
/// primitive's Q values are NaN everywhere it may act, or if `epsilon` is not in [0, 1].
pub fn choose(
    config: &PolicyConfig,
    mode: Mode,
    input: &PolicyInput,
    epsilon: f32,
    rng: &mut impl Rng,
) -> Result<Decision, PolicyError> {
    if !(0.0..=1.0).contains(&epsilon) {
        return Err(PolicyError::Epsilon(epsilon));
    }
    let obs = input.obs;
    check_shape(Primitive::Grasp, input.grasp, obs)?;
    if let Some(push) = input.push {
        check_shape(Primitive::Push, push, obs)?;
    }

    let region = grasps_not_repeating(
        grasp_region(obs, input.goal, config.grasp_margin),
        input.failed_grasps,
        obs,
    );
    let best_grasp = input
        .grasp
        .best_where(&region)
        .ok_or(PolicyError::NoQValue(Primitive::Grasp))?;
    let goal_grasp_q = best_grasp.0;
    let best_push = match input.push {
        Some(push) => {
            let starts = push_region(obs, input.goal, config, input.push_length);
            let best = push
                .best_where(&starts)
                .ok_or(PolicyError::NoQValue(Primitive::Push))?;
            Some((push, starts, best))
        }
        None => None,
    };
    let best_push_q = best_push.as_ref().map(|(_, _, best)| best.0);
    let above = goal_grasp_q > config.q_star;
    // The ring is measured only where the rule reads it.
    let crowded = config.rule == Rule::ThresholdOrCrowded
        && mode == Mode::PushGrasp
        && above
        && occupancy_ratio(obs, input.goal) > config.crowded_border;
    let free = config.free_border.is_some_and(|free| {
        matches!(config.rule, Rule::Threshold | Rule::ThresholdOrCrowded)
            && mode == Mode::PushGrasp
            && !above
            && occupancy_ratio(obs, input.goal) <= free
    });
    let reason = match (best_push_q, config.rule) {
        _ if mode == Mode::GraspOnly => Reason::GraspOnlyMode,
        (_, Rule::Threshold | Rule::ThresholdOrCrowded) if above && !crowded => {
            Reason::AboveThreshold
        }
        _ if free => Reason::BorderFree,
        _ if input.pushes_so_far >= config.max_pushes => Reason::PushBudgetSpent,
        (None, _) => Reason::NoPushMaps,
        (Some(_), Rule::ThresholdOrCrowded) if crowded => Reason::BorderCrowded,
        (Some(_), Rule::Threshold | Rule::ThresholdOrCrowded) => Reason::BelowThreshold,
        (Some(push_q), Rule::HigherQ) if push_q > goal_grasp_q => Reason::PushQHigher,
        (Some(_), Rule::HigherQ) => Reason::GraspQHigher,
    };
    let (primitive, maps, allowed, best) = match best_push {
        Some((push, starts, best))
            if matches!(
                reason,
                Reason::BelowThreshold | Reason::BorderCrowded | Reason::PushQHigher
            ) =>
        {
            (Primitive::Push, push, starts, best)
        }
        _ => (Primitive::Grasp, input.grasp, region, best_grasp),
    };

    // The coin is drawn even at epsilon 0: a greedy step always takes exactly one draw.
    let explored = rng.random::<f32>() < epsilon;
    let (rotation, row, col) = if explored {
        // Never empty: both masks fall back to the whole table.
        uniform_draw(&allowed, obs.side(), rng)
    } else {
        (best.1, best.2, best.3)
    };
    Ok(Decision {
        action: Action {
            primitive,
            rotation,
            row,
            col,
        },
        predicted_q: maps.get(rotation, row, col),
        goal_grasp_q,
        best_push_q,
        explored,
        reason,
        goal_visible: obs.goal_mask(input.goal).contains(&true),
    })
}

/// Grasps of `goal` to try on copies of the scene beside the one `chosen` executes
/// (simulation only): `n` pixels and rotations of the grasp region, drawn as exploration
/// draws them, each with its Q from the `grasp` maps and `chosen`'s view of the state.
pub fn trial_grasps(
    obs: &Heightmaps,
    goal: ObjectId,
    grasp: &QMaps,
    chosen: &Decision,
    n: usize,
    config: &PolicyConfig,
    rng: &mut impl Rng,
) -> Result<Vec<Decision>, PolicyError> {
    check_shape(Primitive::Grasp, grasp, obs)?;
    let region = grasp_region(obs, goal, config.grasp_margin);
    Ok((0..n)
        .map(|_| {
            let (rotation, row, col) = uniform_draw(&region, obs.side(), rng);
            Decision {
                action: Action {
                    primitive: Primitive::Grasp,
                    rotation,
                    row,
                    col,
                },
                predicted_q: grasp.get(rotation, row, col),
                explored: true,
                reason: Reason::Trial,
                ..*chosen
            }
        })
        .collect())
}

/// A rotation and pixel of `allowed` (not all false), uniformly: `allowed` is one
/// `side * side` mask for every rotation, or one per rotation, as [`QMaps::best_where`]
/// reads it.
fn uniform_draw(allowed: &[bool], side: usize, rng: &mut impl Rng) -> (u8, usize, usize) {
    let pixels: Vec<usize> = (0..allowed.len()).filter(|&i| allowed[i]).collect();
    let pixel = pixels[rng.random_range(0..pixels.len())];
    if allowed.len() > side * side {
        let (rotation, pixel) = (pixel / (side * side), pixel % (side * side));
        return (rotation as u8, pixel / side, pixel % side);
    }
    let rotation = rng.random_range(0..ROTATIONS);
    (rotation, pixel / side, pixel % side)
}

/// Q maps must cover the observation's pixels at the simulator's rotations.
fn check_shape(primitive: Primitive, maps: &QMaps, obs: &Heightmaps) -> Result<(), PolicyError> {
    if maps.rotations() == ROTATIONS && maps.side() == obs.side() {
        Ok(())
    } else {
        Err(PolicyError::QMapsShape {
            primitive,
            rotations: maps.rotations(),
            side: maps.side(),
            want_rotations: ROTATIONS,
            want_side: obs.side(),
        })
    }
}
