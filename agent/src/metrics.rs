//! The paper's test metrics. A run is complete when the goal object is picked without 10
//! consecutive failed attempts at grasping it; a grasp of another object is a failed attempt
//! (it counts the goal only, unlike the original `evaluate.py`); a goal pushed out of view
//! fails the run. Per case: completion is the
//! share of complete runs; grasp success is goal grasps over grasp attempts, averaged over the
//! complete runs; motion number is the actions of a complete run, averaged.
//!
//! Goal-agnostic runs (goal [`ANY_OBJECT`]) clear the table instead: every object picked is a
//! success, a run is complete when no object is left without 10 failed attempts in a row,
//! and grasp success is objects picked over grasp attempts.
//!
//! The authors' metric is given beside ours ([`CaseMetrics::any_object_grasp_success`]): their
//! `evaluate.py` counts a grasp as a success when it picked any object (their grasp reward
//! is "the gripper did not close fully"), over the same complete runs.

use serde::{Deserialize, Serialize};
use sim::{ANY_OBJECT, Action, ObjectId, Primitive};
use stats::mean_and_spread;

/// Failed grasp attempts in a row that end a run incomplete.
pub const MAX_FAILED_GRASPS: usize = 10;

/// One action of a test run.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ActionRecord {
    pub primitive: Primitive,
    /// Where it was made, to trace it or make it again on the run's scene; absent from
    /// records written before it was kept.
    #[serde(default)]
    pub at: Option<ActionAt>,
    /// For a grasp: the object it picked, if any.
    pub grasped: Option<ObjectId>,
    /// The goal's best grasp Q when the action was chosen (the policy's discriminator
    /// score), to compare the nets' confidence with what then happened.
    pub goal_grasp_q: f32,
    /// The occupied share of the ring around the goal when the action was chosen
    /// (`sim::measure::occupancy_ratio`); absent from records written before it was kept.
    #[serde(default)]
    pub goal_border_occupancy: Option<f32>,
    /// How far (metres) the goal's centre lay inside the workspace's nearest edge when the
    /// action was chosen (`sim::workspace::inside_by`; negative past it): a goal at the edge
    /// leaves the view at a nudge. Absent from records written before it was kept, and for
    /// a goal-agnostic run.
    #[serde(default)]
    pub goal_inside_edge: Option<f32>,
}

/// Where an action was made: its rotation (of [`sim::ROTATIONS`]) and heightmap pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ActionAt {
    pub rotation: u8,
    pub row: usize,
    pub col: usize,
}

impl From<&Action> for ActionAt {
    fn from(action: &Action) -> Self {
        Self {
            rotation: action.rotation,
            row: action.row,
            col: action.col,
        }
    }
}

/// What happened in one test run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    /// The goal object, or [`ANY_OBJECT`] when the run clears the table.
    pub goal: ObjectId,
    pub actions: Vec<ActionRecord>,
    /// Objects on the table after the last action (what a goal-agnostic run has left).
    pub objects_left: usize,
    /// The goal left the scene without being grasped (pushed wholly out of the camera's
    /// view): the run has failed, however many actions remain.
    #[serde(default)]
    pub goal_lost: bool,
    /// Updates the nets took during the run (learning during the test; 0 without).
    #[serde(default)]
    pub updates: usize,
}

/// A run judged by the paper's rules.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RunOutcome {
    pub complete: bool,
    /// Complete, or failed out: more actions would not change the outcome.
    pub decided: bool,
    /// Actions up to the goal grasp, or the table cleared (all of them for an incomplete run).
    pub actions: usize,
    pub grasp_attempts: usize,
    /// Grasps that picked the goal (any object in a goal-agnostic run).
    pub grasp_successes: usize,
    /// Grasps that picked any object (the authors' success).
    pub objects_picked: usize,
}

impl RunRecord {
    /// The run judged: actions after the goal grasp or after the 10th failure in a row do
    /// not count.
    pub fn outcome(&self) -> RunOutcome {
        let clearing = self.goal == ANY_OBJECT;
        let mut failures_in_a_row = 0;
        let mut judged = RunOutcome {
            complete: false,
            decided: false,
            actions: 0,
            grasp_attempts: 0,
            grasp_successes: 0,
            objects_picked: 0,
        };
        for (i, action) in self.actions.iter().enumerate() {
            if action.primitive != Primitive::Grasp {
                continue;
            }
            judged.grasp_attempts += 1;
            judged.objects_picked += usize::from(action.grasped.is_some());
            let success = match action.grasped {
                Some(_) if clearing => true,
                grasped => grasped == Some(self.goal),
            };
            if success {
                judged.grasp_successes += 1;
                failures_in_a_row = 0;
                if !clearing {
                    return RunOutcome {
                        complete: true,
                        decided: true,
                        actions: i + 1,
                        ..judged
                    };
                }
                continue;
            }
            failures_in_a_row += 1;
            if failures_in_a_row == MAX_FAILED_GRASPS {
                return RunOutcome {
                    decided: true,
                    actions: i + 1,
                    ..judged
                };
            }
        }
        let cleared = clearing && self.objects_left == 0;
        RunOutcome {
            complete: cleared,
            decided: cleared || self.goal_lost,
            actions: self.actions.len(),
            ..judged
        }
    }
}

/// A test case's figures (fractions, not percentages). Grasp success and motion number are
/// over the complete runs, so they are `None` when no run completed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CaseMetrics {
    pub runs: usize,
    pub complete_runs: usize,
    pub completion: f64,
    pub grasp_success: Option<f64>,
    /// The standard error of `grasp_success`, from the spread of the complete runs' own
    /// success: how far other jitters or random scenes (another eval seed) would move it for
    /// the same nets. `None` below two complete runs.
    #[serde(default)]
    pub grasp_success_se: Option<f64>,
    pub motion_number: Option<f64>,
    /// The authors' grasp success: grasps that picked any object over grasp attempts,
    /// averaged over the same complete runs.
    #[serde(default)]
    pub any_object_grasp_success: Option<f64>,
}

impl CaseMetrics {
    pub fn of(outcomes: &[RunOutcome]) -> Self {
        let complete: Vec<&RunOutcome> = outcomes.iter().filter(|o| o.complete).collect();
        let mean = |f: &dyn Fn(&RunOutcome) -> f64| {
            (!complete.is_empty())
                .then(|| complete.iter().map(|o| f(o)).sum::<f64>() / complete.len() as f64)
        };
        let successes: Vec<f64> = complete
            .iter()
            .map(|o| o.grasp_successes as f64 / o.grasp_attempts.max(1) as f64)
            .collect();
        let spread = mean_and_spread(&successes);
        let grasp_success_se = spread
            .filter(|_| successes.len() >= 2)
            .map(|(_, sd)| sd / (successes.len() as f64).sqrt());
        CaseMetrics {
            runs: outcomes.len(),
            complete_runs: complete.len(),
            completion: complete.len() as f64 / outcomes.len().max(1) as f64,
            grasp_success: spread.map(|(mean, _)| mean),
            grasp_success_se,
            motion_number: mean(&|o| o.actions as f64),
            any_object_grasp_success: mean(&|o| {
                o.objects_picked as f64 / o.grasp_attempts.max(1) as f64
            }),
        }
    }

    /// The mean of several cases' figures, as the paper averages its cases (a case with no
    /// complete run leaves grasp success and motion number to the others). The cases' runs
    /// are independent, so the mean's standard error is the root of their squared errors'
    /// sum over their count; `None` if a case in the mean has none.
    pub fn average(cases: &[CaseMetrics]) -> Self {
        let mean = |values: Vec<f64>| {
            (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
        };
        let succeeding: Vec<&CaseMetrics> =
            cases.iter().filter(|c| c.grasp_success.is_some()).collect();
        let grasp_success_se = succeeding
            .iter()
            .map(|c| c.grasp_success_se.map(|se| se * se))
            .sum::<Option<f64>>()
            .filter(|_| !succeeding.is_empty())
            .map(|squares| squares.sqrt() / succeeding.len() as f64);
        CaseMetrics {
            runs: cases.iter().map(|c| c.runs).sum(),
            complete_runs: cases.iter().map(|c| c.complete_runs).sum(),
            completion: mean(cases.iter().map(|c| c.completion).collect()).unwrap_or(0.0),
            grasp_success: mean(succeeding.iter().filter_map(|c| c.grasp_success).collect()),
            grasp_success_se,
            motion_number: mean(cases.iter().filter_map(|c| c.motion_number).collect()),
            any_object_grasp_success: mean(
                succeeding
                    .iter()
                    .filter_map(|c| c.any_object_grasp_success)
                    .collect(),
            ),
        }
    }
}
