//! The paper's metrics on hand-made test runs.

use agent::metrics::MAX_FAILED_GRASPS;
use agent::{ActionRecord, CaseMetrics, RunRecord};
use sim::{ANY_OBJECT, Primitive};

const GOAL: u8 = 4;

fn push() -> ActionRecord {
    ActionRecord {
        primitive: Primitive::Push,
        at: None,
        grasped: None,
        goal_grasp_q: 0.0,
        goal_border_occupancy: None,
        goal_inside_edge: None,
    }
}

fn grasp(grasped: Option<u8>) -> ActionRecord {
    ActionRecord {
        primitive: Primitive::Grasp,
        at: None,
        grasped,
        goal_grasp_q: 0.0,
        goal_border_occupancy: None,
        goal_inside_edge: None,
    }
}

fn run(actions: Vec<ActionRecord>) -> RunRecord {
    RunRecord {
        goal: GOAL,
        actions,
        objects_left: 3,
        goal_lost: false,
        updates: 0,
    }
}

/// A goal-agnostic run that left `objects_left` objects on the table.
fn clearing(actions: Vec<ActionRecord>, objects_left: usize) -> RunRecord {
    RunRecord {
        goal: ANY_OBJECT,
        actions,
        objects_left,
        goal_lost: false,
        updates: 0,
    }
}

#[test]
fn pushes_then_the_goal_complete_a_run_counting_every_action() {
    let outcome = run(vec![push(), push(), grasp(Some(GOAL))]).outcome();
    assert!(outcome.complete && outcome.decided);
    assert_eq!((outcome.actions, outcome.grasp_attempts), (3, 1));
}

#[test]
fn a_goal_pushed_off_the_table_fails_the_run_at_once() {
    let outcome = RunRecord {
        goal_lost: true,
        ..run(vec![push(), push(), grasp(None)])
    }
    .outcome();
    assert!(!outcome.complete && outcome.decided);
    assert_eq!(outcome.actions, 3);
}

#[test]
fn another_object_grasped_is_a_failed_attempt_not_a_success() {
    let outcome = run(vec![grasp(Some(2)), push(), grasp(None), grasp(Some(GOAL))]).outcome();
    assert!(outcome.complete);
    assert_eq!((outcome.actions, outcome.grasp_attempts), (4, 3));
    assert_eq!((outcome.grasp_successes, outcome.objects_picked), (1, 2));
    let only_others = run(vec![grasp(Some(1)), grasp(Some(2)), grasp(Some(3))]).outcome();
    assert!(!only_others.complete && !only_others.decided);
}

#[test]
fn ten_failed_attempts_in_a_row_end_the_run_and_a_later_goal_grasp_does_not_count() {
    let mut actions: Vec<ActionRecord> = (0..MAX_FAILED_GRASPS)
        .flat_map(|i| [push(), grasp(if i % 2 == 0 { None } else { Some(1) })])
        .collect();
    let failed_at = actions.len();
    actions.push(grasp(Some(GOAL)));
    let outcome = run(actions).outcome();
    assert!(!outcome.complete && outcome.decided);
    assert_eq!(outcome.actions, failed_at);
    assert_eq!(outcome.grasp_attempts, MAX_FAILED_GRASPS);

    // Nine failures leave room for the goal.
    let mut actions: Vec<ActionRecord> = (0..MAX_FAILED_GRASPS - 1).map(|_| grasp(None)).collect();
    actions.push(grasp(Some(GOAL)));
    assert!(run(actions).outcome().complete);
}

#[test]
fn case_figures_average_over_complete_runs_only() {
    let outcomes = [
        run(vec![grasp(Some(GOAL))]).outcome(), // 1 action, 1/1
        run(vec![push(), grasp(None), grasp(Some(GOAL))]).outcome(), // 3 actions, 1/2
        run(vec![grasp(None); MAX_FAILED_GRASPS]).outcome(), // incomplete
        run(vec![
            push(),
            grasp(Some(3)),
            push(),
            push(),
            grasp(Some(GOAL)),
        ])
        .outcome(), // 5, 1/2
    ];
    let case = CaseMetrics::of(&outcomes);
    assert_eq!((case.runs, case.complete_runs), (4, 3));
    assert!((case.completion - 0.75).abs() < 1e-12);
    assert!((case.grasp_success.unwrap() - (1.0 + 0.5 + 0.5) / 3.0).abs() < 1e-12);
    // The complete runs' successes 1, 1/2, 1/2: sample variance 1/12, over 3 runs.
    let se = (1.0f64 / 12.0 / 3.0).sqrt();
    assert!((case.grasp_success_se.unwrap() - se).abs() < 1e-12);
    assert!((case.motion_number.unwrap() - 3.0).abs() < 1e-12);

    // The authors' metric counts the grasp of object 3 too: 1, 1/2, 1.
    assert!((case.any_object_grasp_success.unwrap() - 2.5 / 3.0).abs() < 1e-12);

    let none_complete = CaseMetrics::of(&outcomes[2..3]);
    assert_eq!(none_complete.completion, 0.0);
    assert_eq!(none_complete.grasp_success, None);
    assert_eq!(none_complete.grasp_success_se, None);
    let mean = CaseMetrics::average(&[case, none_complete]);
    assert!((mean.completion - 0.375).abs() < 1e-12);
    assert_eq!(mean.grasp_success, case.grasp_success);
    assert_eq!(mean.grasp_success_se, case.grasp_success_se);
    assert_eq!(none_complete.any_object_grasp_success, None);
    assert_eq!(mean.any_object_grasp_success, case.any_object_grasp_success);
    assert_eq!(mean.runs, 5);
    // Two cases with errors: the mean's error is the root of the squares' sum over 2.
    let two = CaseMetrics::average(&[case, case]);
    assert!((two.grasp_success_se.unwrap() - se / 2f64.sqrt()).abs() < 1e-12);
    // One complete run has no spread to measure, and a mean over it has no error either.
    let single = CaseMetrics::of(&outcomes[..1]);
    assert_eq!(single.complete_runs, 1);
    assert_eq!(single.grasp_success_se, None);
    assert_eq!(CaseMetrics::average(&[case, single]).grasp_success_se, None);
}

#[test]
fn a_goal_agnostic_run_completes_when_the_table_is_clear_and_every_pick_is_a_success() {
    let actions = vec![
        grasp(Some(2)),
        push(),
        grasp(None),
        grasp(Some(5)),
        grasp(Some(1)),
    ];
    let cleared = clearing(actions.clone(), 0).outcome();
    assert!(cleared.complete && cleared.decided);
    assert_eq!(
        (
            cleared.actions,
            cleared.grasp_attempts,
            cleared.grasp_successes
        ),
        (5, 4, 3)
    );
    let case = CaseMetrics::of(&[cleared]);
    assert!((case.grasp_success.unwrap() - 0.75).abs() < 1e-12);

    // Objects left: the run goes on (a goal run would have ended at its first pick of GOAL).
    let unfinished = clearing(actions, 1).outcome();
    assert!(!unfinished.complete && !unfinished.decided);
}

#[test]
fn a_pick_resets_the_goal_agnostic_failure_count_and_ten_in_a_row_end_the_run() {
    let nine_misses = || vec![grasp(None); MAX_FAILED_GRASPS - 1];
    let mut actions = nine_misses();
    actions.push(grasp(Some(1)));
    actions.extend(nine_misses());
    actions.push(grasp(Some(2)));
    assert!(clearing(actions.clone(), 0).outcome().complete);

    actions.extend(vec![grasp(None); MAX_FAILED_GRASPS]);
    let failed = clearing(actions.clone(), 0).outcome();
    assert!(!failed.complete && failed.decided);
    assert_eq!(failed.actions, actions.len());
}
