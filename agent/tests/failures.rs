//! Why runs failed, on hand-made test runs: each grasp and push classed, each incomplete run
//! by how it ended, and the grasps binned by their goal grasp Q.

use agent::metrics::MAX_FAILED_GRASPS;
use agent::{ActionRecord, FailureReport, RunRecord};
use sim::Primitive;

const GOAL: u8 = 4;

fn action(primitive: Primitive, grasped: Option<u8>, q: f32, border: f32) -> ActionRecord {
    ActionRecord {
        primitive,
        at: None,
        grasped,
        goal_grasp_q: q,
        goal_border_occupancy: Some(border),
        goal_inside_edge: None,
    }
}

fn push(q: f32, border: f32) -> ActionRecord {
    action(Primitive::Push, None, q, border)
}

fn grasp(grasped: Option<u8>, q: f32) -> ActionRecord {
    action(Primitive::Grasp, grasped, q, 0.0)
}

fn run(actions: Vec<ActionRecord>, goal_lost: bool) -> RunRecord {
    RunRecord {
        goal: GOAL,
        actions,
        objects_left: 5,
        goal_lost,
        updates: 0,
    }
}

#[test]
fn grasps_pushes_and_incomplete_runs_are_classed_and_grasps_binned_by_their_q() {
    let runs = [
        // Complete: a push that raised the goal's Q and freed its border, a miss, the same
        // miss again, then the goal.
        run(
            vec![
                push(1.2, 0.6),
                grasp(None, 1.9),
                grasp(None, 1.93),
                grasp(Some(GOAL), 2.5),
            ],
            false,
        ),
        // Out of attempts: ten grasps that picked another object, the goal grasp after them
        // not counted.
        run(
            (0..MAX_FAILED_GRASPS)
                .map(|i| grasp(Some(1), 1.05 + 0.1 * i as f32))
                .chain([grasp(Some(GOAL), 2.5)])
                .collect(),
            false,
        ),
        // The goal lost: a push that did neither, a push that freed the border only, then a
        // push off the table (not judged).
        run(vec![push(1.5, 0.5), push(1.55, 0.5), push(1.6, 0.2)], true),
        // A grasp that knocked the goal off the table.
        run(vec![grasp(None, 1.7)], true),
        // Undecided at the guard, after a push that did neither.
        run(vec![push(0.85, 0.0), grasp(Some(2), 0.9)], false),
    ];
    let report = FailureReport::of(&runs);
    assert_eq!(
        (
            report.runs,
            report.complete,
            report.out_of_attempts,
            report.goal_lost,
            report.undecided
        ),
        (5, 1, 1, 2, 1)
    );

    let g = report.grasps;
    assert_eq!(g.attempts, 4 + MAX_FAILED_GRASPS + 1);
    assert_eq!(
        (g.goal, g.nothing, g.other_object),
        (1, 3, MAX_FAILED_GRASPS + 1)
    );
    assert_eq!(g.goal_knocked_off, 1);
    // 1.9 then 1.93 is a repeat; the other objects' grasps climb by 0.1 a try: none.
    assert_eq!(g.repeats, 1);

    let p = report.pushes;
    assert_eq!(p.pushes, 5);
    assert_eq!(
        (p.raised_q, p.freed_border, p.both, p.neither, p.unjudged),
        (1, 2, 1, 2, 1)
    );

    let bins: Vec<(usize, usize)> = report
        .reliability
        .iter()
        .map(|b| (b.grasps, b.picked_goal))
        .collect();
    // <1.0: 0.9; 1.0-1.5: 1.05 .. 1.45; 1.5-1.8: 1.55 .. 1.75 and the knock-off's 1.7;
    // 1.8-2.0: 1.85, 1.95, 1.9, 1.93; >= 2.4: the goal's 2.5.
    assert_eq!(
        bins,
        vec![(1, 0), (5, 0), (4, 0), (4, 0), (0, 0), (0, 0), (1, 1)]
    );
    assert_eq!(report.reliability[6].rate(), Some(1.0));
    assert_eq!(report.reliability[4].rate(), None);
    assert_eq!(report.reliability[0].from, None);
    assert_eq!(report.reliability[6].to, None);
}

#[test]
fn records_from_before_the_border_was_kept_leave_their_pushes_unjudged() {
    let old = ActionRecord {
        goal_border_occupancy: None,
        ..push(1.0, 0.0)
    };
    let report = FailureReport::of(&[run(vec![old, grasp(Some(GOAL), 2.0)], false)]);
    assert_eq!((report.pushes.pushes, report.pushes.unjudged), (1, 1));
    assert_eq!(report.complete, 1);
}
