//! Evaluation runs on real scenes with real (untrained) nets: deterministic for a fixed
//! seed whatever the number of threads, and every run ends decided or at the guard.

use std::path::Path;

use agent::{Agent, EvalConfig, Scene, TestLearning, evaluate};
use learner::{LearningConfig, TrainedNet};
use policy::{Mode, PolicyConfig, PushReward};
use qnet::{Device, QNetConfig};
use sim::{ANY_OBJECT, Arrangement, SimConfig};

fn cases() -> Vec<(String, Scene)> {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/arrangements/challenging-00.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let arrangement = Arrangement::parse_toml(&text, &path).unwrap();
    vec![
        ("challenging-00".into(), Scene::Arrangement(arrangement)),
        ("random-8".into(), Scene::Random { objects: 8 }),
    ]
}

fn small_net() -> QNetConfig {
    QNetConfig {
        trunk_widths: vec![4, 8],
        head_width: 16,
        ..QNetConfig::default()
    }
}

/// Untrained nets on the same weights in every worker (the weights seeded once).
fn same_agent() -> impl Fn() -> Agent + Sync {
    let sim = SimConfig::with_pixel_size(0.004);
    let make = move || {
        Agent::new(
            &small_net(),
            &sim,
            PolicyConfig::default(),
            Mode::PushGrasp,
            &Device::flex(),
        )
    };
    let weights = make().nets().to_bytes().unwrap();
    move || {
        let mut agent = make();
        agent.load_weights(&weights).unwrap();
        agent
    }
}

fn small_eval() -> EvalConfig {
    EvalConfig {
        sim: SimConfig::with_pixel_size(0.004),
        runs: 2,
        seed: 3,
        max_actions: 8,
        ..EvalConfig::default()
    }
}

#[test]
fn evaluation_is_deterministic_for_a_seed_and_judges_every_run() {
    let make_same = same_agent();
    let config = small_eval();
    let cases = cases();
    let parallel = evaluate(&make_same, &cases, &config).unwrap();
    let serial = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| evaluate(&make_same, &cases, &config).unwrap());
    for (a, b) in parallel.iter().zip(&serial) {
        assert_eq!(a.runs, b.runs, "{}", a.name);
        assert_eq!(a.metrics, b.metrics);
    }
    for case in &parallel {
        assert_eq!(case.runs.len(), 2);
        for run in &case.runs {
            let outcome = run.outcome();
            assert!(outcome.decided || run.actions.len() == 8, "{run:?}");
            assert!(!run.actions.is_empty());
        }
    }
    assert_eq!(parallel[0].runs[0].goal, 5, "the arrangement's goal");
    assert!(
        parallel
            .iter()
            .flat_map(|case| &case.runs)
            .all(|run| run.outcome().complete
                == run
                    .actions
                    .last()
                    .unwrap()
                    .grasped
                    .is_some_and(|id| id == run.goal)),
        "a goal run ends at its goal's pick"
    );

    // Goal-agnostic: every object is the goal; a run ends with the table clear, ten misses in
    // a row, or at the guard of 8 actions per object.
    let agnostic = EvalConfig {
        goal_agnostic: true,
        ..config.clone()
    };
    let cleared = evaluate(&make_same, &cases, &agnostic).unwrap();
    for run in cleared.iter().flat_map(|case| &case.runs) {
        assert_eq!(run.goal, ANY_OBJECT);
        let outcome = run.outcome();
        let picks = run.actions.iter().filter(|a| a.grasped.is_some()).count();
        assert_eq!(outcome.grasp_successes, picks, "every pick counts: {run:?}");
        assert_eq!(outcome.complete, run.objects_left == 0, "{run:?}");
        assert!(outcome.decided || run.objects_left > 0, "{run:?}");
    }
    // Another seed gives other scenes (the random case differs).
    let other = evaluate(&make_same, &cases[1..], &EvalConfig { seed: 4, ..config }).unwrap();
    assert_ne!(other[0].runs, parallel[1].runs);
}

#[test]
fn a_run_that_learns_updates_after_every_labelled_action_from_the_checkpoints_nets() {
    let make_same = same_agent();
    let cases = &cases()[..1];
    let frozen_config = EvalConfig {
        runs: 3,
        ..small_eval()
    };
    let learning = EvalConfig {
        learning: Some(TestLearning {
            net: small_net(),
            learning: LearningConfig::default(),
            trained: vec![TrainedNet::Grasp, TrainedNet::Push],
            push_reward: PushReward::Dense,
        }),
        ..frozen_config.clone()
    };
    // One worker: each run follows the one before on the same agent, so a run that did not
    // start from the checkpoint's nets would show it.
    let serial = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let (frozen, learned) = serial.install(|| {
        (
            evaluate(&make_same, cases, &frozen_config).unwrap(),
            evaluate(&make_same, cases, &learning).unwrap(),
        )
    });
    let mut changed = false;
    for (frozen, learned) in frozen[0].runs.iter().zip(&learned[0].runs) {
        assert_eq!(frozen.updates, 0);
        // Every action but the last is labelled by the decision after it.
        assert_eq!(learned.updates, learned.actions.len() - 1, "{learned:?}");
        // The first two decisions are the checkpoint's nets': an update acts one decision
        // after the action it learned from.
        let first = frozen.actions.len().min(learned.actions.len()).min(2);
        assert_eq!(frozen.actions[..first], learned.actions[..first]);
        changed |= frozen.actions != learned.actions;
    }
    assert!(changed, "learning changed no run: {learned:?}");

    // A goal-agnostic test has no goal to label: refused.
    let agnostic = EvalConfig {
        goal_agnostic: true,
        ..learning
    };
    assert!(evaluate(&make_same, cases, &agnostic).is_err());
}
