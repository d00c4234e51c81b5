//! Evaluation runs on real scenes with real (untrained) nets: deterministic for a fixed
//! seed whatever the number of threads, and every run ends decided or at the guard.

use std::path::Path;

use agent::{Agent, EvalConfig, Scene, evaluate};
use policy::{Mode, PolicyConfig};
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

#[test]
fn evaluation_is_deterministic_for_a_seed_and_judges_every_run() {
    let sim = SimConfig::with_pixel_size(0.004);
    let side = sim.grid().unwrap().side();
    let net = QNetConfig {
        trunk_widths: vec![4, 8],
        head_width: 16,
        ..QNetConfig::default()
    };
    let make = || {
        Agent::new(
            &net,
            side,
            PolicyConfig::default(),
            Mode::PushGrasp,
            &Device::flex(),
        )
    };
    // Untrained nets on the same weights in every worker: seed the weights once.
    let weights = make().nets().to_bytes().unwrap();
    let make_same = || {
        let mut agent = make();
        agent.load_weights(&weights).unwrap();
        agent
    };
    let config = EvalConfig {
        sim,
        runs: 2,
        seed: 3,
        max_actions: 8,
        ..EvalConfig::default()
    };
    let cases = cases();
    let parallel = evaluate(make_same, &cases, &config).unwrap();
    let serial = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| evaluate(make_same, &cases, &config).unwrap());
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
    let cleared = evaluate(make_same, &cases, &agnostic).unwrap();
    for run in cleared.iter().flat_map(|case| &case.runs) {
        assert_eq!(run.goal, ANY_OBJECT);
        let outcome = run.outcome();
        let picks = run.actions.iter().filter(|a| a.grasped.is_some()).count();
        assert_eq!(outcome.grasp_successes, picks, "every pick counts: {run:?}");
        assert_eq!(outcome.complete, run.objects_left == 0, "{run:?}");
        assert!(outcome.decided || run.objects_left > 0, "{run:?}");
    }
    // Another seed gives other scenes (the random case differs).
    let other = evaluate(make_same, &cases[1..], &EvalConfig { seed: 4, ..config }).unwrap();
    assert_ne!(other[0].runs, parallel[1].runs);
}
