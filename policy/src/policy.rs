//! The hierarchical push-grasp policy: the grasp net is the discriminator (grasp once the
//! goal's grasp Q exceeds Q*), the push net acts below it (at most five pushes, then a
//! grasp), and epsilon-greedy exploration draws the chosen primitive's pixel and rotation.
//! The goal-conditioned VPG baseline swaps the discriminator for VPG's rule, and the
//! authors' test-time rule adds a crowded-border test to it ([`Rule`]).
//!
//! The masks it chooses within are [`crate::regions`]; the rule, its settings and the trial
//! grasps drawn as it explores are here, read together against the paper.

use rand::{Rng, RngExt};
use serde::{Deserialize, Serialize};
use sim::measure::occupancy_ratio;
use sim::{Action, Heightmaps, ObjectId, Primitive, ROTATIONS};

use crate::config::{PolicyConfig, Rule};
use crate::error::PolicyError;
use crate::push_retreat::push_start_clear_of_goal;
use crate::qmaps::QMaps;
use crate::regions::{grasp_choices, grasp_region, push_region};

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
    /// The scene rendered finer for the landing guard, on [`PolicyConfig::landing_view`]'s
    /// grid where it names one; without it the guard reads `obs` alone.
    pub landing_view: Option<&'a Heightmaps>,
    /// Grasps that picked nothing, remembered by the caller (the test loop under `eval
    /// --avoid-failed-grasps`; empty otherwise): none is chosen again, nor a grasp near it
    /// ([`REPEAT_RADIUS`](crate::REPEAT_RADIUS)).
    pub failed_grasps: &'a [Action],
    /// Whether a grasp in this run has picked nothing since its last push (the test loop
    /// knows; a training episode ends at its grasp), for
    /// [`PolicyConfig::free_border_once`].
    pub grasp_failed_since_push: bool,
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

/// Picks the next action. Grasp when `mode` is grasp-only, the push budget is spent, or
/// there are no push maps; otherwise the config's [`Rule`] decides (the paper's: grasp when
/// the goal's grasp Q exceeds Q*, else push; under `free_border`, also grasp when the goal's
/// border ring is free, unless under `free_border_once` a grasp has failed since the last
/// push). The primitive goes to the argmax of its Q maps
/// over its allowed pixels ([`grasp_choices`], [`push_region`]) and all rotations, or,
/// with probability `epsilon`, to a pixel and rotation drawn uniformly from the same set;
/// under `landing_retreat`, a push whose jaws would come down on the goal starts farther
/// back ([`push_start_clear_of_goal`]). Deterministic given `rng`.
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

    let region = grasp_choices(obs, input.goal, config, input.failed_grasps);
    let best_grasp = input
        .grasp
        .best_where(&region)
        .ok_or(PolicyError::NoQValue(Primitive::Grasp))?;
    let goal_grasp_q = best_grasp.0;
    let best_push = match input.push {
        Some(push) => {
            let starts = push_region(
                obs,
                input.landing_view,
                input.goal,
                config,
                input.push_length,
            );
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
            && !(config.free_border_once && input.grasp_failed_since_push)
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
    let retreat = (
        config.landing_retreat,
        config.landing_guard,
        input.landing_view,
    );
    let [row, col] = match (primitive, retreat) {
        (Primitive::Push, (Some(distance), Some(margin), Some(view))) => push_start_clear_of_goal(
            obs,
            view,
            input.goal,
            margin,
            rotation,
            [row, col],
            &allowed,
            distance,
        ),
        _ => [row, col],
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
