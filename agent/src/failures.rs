//! Why test runs fail, read from their records (what `eval --runs-json` writes): how the
//! incomplete runs ended, what each grasp picked, what each push did for the goal, and how
//! often grasps chosen at each goal grasp Q picked the goal (the Q's reliability, which the
//! policy's Q* gate trusts). Only the actions up to a run's judged end count.

use policy::Q_IMPROVEMENT;
use serde::{Deserialize, Serialize};
use sim::Primitive;

use crate::metrics::{ActionRecord, RunRecord};

/// A push frees the goal's border when the ring's occupied share falls by more than this
/// (the push reward's change test, `sim::measure`).
const BORDER_FREED: f32 = 0.1;

/// A failed grasp repeats the failed grasp before it when their goal grasp Qs are this
/// close: the same choice again.
const REPEAT_Q: f32 = 0.05;

/// The goal grasp Q's bin edges: the policy's Q* (1.8) and the labels' fixed point (2.0)
/// among them.
pub const Q_BIN_EDGES: [f32; 6] = [1.0, 1.5, 1.8, 2.0, 2.2, 2.4];

/// Why a set of runs failed.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FailureReport {
    pub runs: usize,
    pub complete: usize,
    /// Incomplete runs ended by ten failed grasps in a row ...
    pub out_of_attempts: usize,
    /// ... by the goal leaving the table ...
    pub goal_lost: usize,
    /// ... or still undecided at the action guard.
    pub undecided: usize,
    pub grasps: GraspCounts,
    pub pushes: PushCounts,
    /// Grasps by the goal's grasp Q when they were chosen (bins split at [`Q_BIN_EDGES`]).
    pub reliability: Vec<QBin>,
}

/// What the grasps picked.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GraspCounts {
    pub attempts: usize,
    pub goal: usize,
    pub nothing: usize,
    pub other_object: usize,
    /// Failed grasps after which the goal was out of view.
    pub goal_knocked_off: usize,
    /// Failed grasps right after a failed grasp at a goal grasp Q within 0.05 of it.
    pub repeats: usize,
}

/// What the pushes did for the goal, judged by the next decision's view of it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PushCounts {
    pub pushes: usize,
    /// Raised the goal's grasp Q by more than the push reward's 0.1.
    pub raised_q: usize,
    /// Lowered the occupied share of the goal's border ring by more than 0.1.
    pub freed_border: usize,
    /// Did both.
    pub both: usize,
    /// Did neither.
    pub neither: usize,
    /// Were not followed by a decision (the goal left the table), or predate the border's
    /// record.
    pub unjudged: usize,
}

/// The grasps chosen at a goal grasp Q in `[from, to)` (`None`: unbounded) and how many
/// picked the goal.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct QBin {
    pub from: Option<f32>,
    pub to: Option<f32>,
    pub grasps: usize,
    pub picked_goal: usize,
}

impl QBin {
    /// The share of the bin's grasps that picked the goal; `None` for an empty bin.
    pub fn rate(&self) -> Option<f64> {
        (self.grasps > 0).then(|| self.picked_goal as f64 / self.grasps as f64)
    }
}

impl FailureReport {
    /// The report of `runs` (goal runs; a goal-agnostic run has no goal to fail on).
    pub fn of<'a>(runs: impl IntoIterator<Item = &'a RunRecord>) -> Self {
        let mut report = FailureReport {
            reliability: q_bins(),
            ..FailureReport::default()
        };
        for run in runs {
            report.add(run);
        }
        report
    }

    fn add(&mut self, run: &RunRecord) {
        let outcome = run.outcome();
        self.runs += 1;
        match outcome {
            o if o.complete => self.complete += 1,
            o if !o.decided => self.undecided += 1,
            _ if run.goal_lost => self.goal_lost += 1,
            _ => self.out_of_attempts += 1,
        }
        let judged = &run.actions[..outcome.actions];
        for (i, action) in judged.iter().enumerate() {
            let next = judged.get(i + 1);
            match action.primitive {
                Primitive::Grasp => {
                    self.add_grasp(run, action, i.checked_sub(1).map(|p| &judged[p]), next)
                }
                Primitive::Push => self.add_push(action, next),
            }
        }
    }

    fn add_grasp(
        &mut self,
        run: &RunRecord,
        grasp: &ActionRecord,
        before: Option<&ActionRecord>,
        next: Option<&ActionRecord>,
    ) {
        let g = &mut self.grasps;
        g.attempts += 1;
        let picked_goal = grasp.grasped == Some(run.goal);
        match grasp.grasped {
            _ if picked_goal => g.goal += 1,
            Some(_) => g.other_object += 1,
            None => g.nothing += 1,
        }
        if !picked_goal && next.is_none() && run.goal_lost {
            g.goal_knocked_off += 1;
        }
        let failed =
            |a: &ActionRecord| a.primitive == Primitive::Grasp && a.grasped != Some(run.goal);
        if !picked_goal
            && before.is_some_and(|b| {
                failed(b) && (b.goal_grasp_q - grasp.goal_grasp_q).abs() <= REPEAT_Q
            })
        {
            g.repeats += 1;
        }
        let bin = Q_BIN_EDGES
            .iter()
            .take_while(|&&edge| grasp.goal_grasp_q >= edge)
            .count();
        self.reliability[bin].grasps += 1;
        self.reliability[bin].picked_goal += usize::from(picked_goal);
    }

    fn add_push(&mut self, push: &ActionRecord, next: Option<&ActionRecord>) {
        let p = &mut self.pushes;
        p.pushes += 1;
        let Some(next) = next else {
            p.unjudged += 1;
            return;
        };
        let (Some(before), Some(after)) = (push.goal_border_occupancy, next.goal_border_occupancy)
        else {
            p.unjudged += 1;
            return;
        };
        let raised = next.goal_grasp_q - push.goal_grasp_q > Q_IMPROVEMENT;
        let freed = before - after > BORDER_FREED;
        p.raised_q += usize::from(raised);
        p.freed_border += usize::from(freed);
        p.both += usize::from(raised && freed);
        p.neither += usize::from(!raised && !freed);
    }
}

/// Empty bins split at [`Q_BIN_EDGES`], the first unbounded below, the last above.
fn q_bins() -> Vec<QBin> {
    let edges: Vec<Option<f32>> = std::iter::once(None)
        .chain(Q_BIN_EDGES.map(Some))
        .chain([None])
        .collect();
    edges
        .windows(2)
        .map(|w| QBin {
            from: w[0],
            to: w[1],
            grasps: 0,
            picked_goal: 0,
        })
        .collect()
}
