//! `pushgrasp eval` on a checkpoint of a short real run: the paper's table as JSON, the same
//! figures for the same seed, and clear errors for what cannot be tested; `scene grasps`
//! scores the same checkpoint's grasp net.

use std::path::Path;

use serde_json::Value;

mod common;
use common::{pushgrasp_fails, pushgrasp_ok};

#[test]
fn eval_scores_a_checkpoint_the_same_way_for_the_same_seed() {
    let logs = tempfile::tempdir().unwrap();
    let logs_dir = logs.path().to_str().unwrap();
    pushgrasp_ok(&[
        "train",
        "--config",
        "configs/stage1.toml",
        "--threads",
        "--actors",
        "1",
        "--episodes",
        "10",
        "--run-id",
        "eval",
        "--logs",
        logs_dir,
    ]);
    let checkpoint = logs.path().join("eval/checkpoint");
    let checkpoint = checkpoint.to_str().unwrap();
    let runs_json = logs.path().join("runs.jsonl");
    // The table as JSON for `seed`, with `more` arguments.
    let eval = |seed: &str, more: &[&str]| -> Value {
        let mut args = vec![
            "eval",
            "--checkpoint",
            checkpoint,
            "--arrangements",
            "configs/arrangements/challenging-05.toml",
            "--random",
            "6",
            "--runs",
            "2",
            "--seed",
            seed,
            "--json",
            "--runs-json",
            runs_json.to_str().unwrap(),
        ];
        args.extend(more);
        serde_json::from_str(&pushgrasp_ok(&args)).unwrap()
    };
    let first = eval("1", &[]);
    assert_eq!(
        first,
        eval("1", &[]),
        "same checkpoint, same seed, same figures"
    );
    let cases = first["cases"].as_array().unwrap();
    assert_eq!(cases[0]["case"], "challenging-05");
    assert_eq!(cases[1]["case"], "random-6");
    for case in cases {
        assert_eq!(case["runs"], 2);
        let completion = case["completion"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&completion));
        // Grasp success and motion number exist exactly when some run completed.
        assert_eq!(
            case["complete_runs"].as_u64().unwrap() > 0,
            case["motion_number"].is_number()
        );
        // ... and its standard error when two did.
        assert_eq!(
            case["complete_runs"].as_u64().unwrap() >= 2,
            case["grasp_success_se"].is_number()
        );
    }
    // Every run is written out, and its outcome agrees with its case's figures.
    let lines: Vec<Value> = std::fs::read_to_string(&runs_json)
        .unwrap()
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .collect();
    assert_eq!(lines.len(), 4);
    for case in cases {
        let runs: Vec<&Value> = lines.iter().filter(|l| l["case"] == case["case"]).collect();
        assert_eq!(runs.len(), 2);
        let complete = runs.iter().filter(|l| l["outcome"]["complete"] == true);
        assert_eq!(
            complete.count() as u64,
            case["complete_runs"].as_u64().unwrap()
        );
        for run in runs {
            let actions = run["actions"].as_array().unwrap();
            assert!(!actions.is_empty());
            assert!(actions.iter().all(|a| a["goal_grasp_q"].is_number()));
            // Where each action was made: a rotation and a pixel of the heightmap.
            assert!(actions.iter().all(|a| {
                a["at"]["rotation"]
                    .as_u64()
                    .is_some_and(|r| r < u64::from(sim::ROTATIONS))
                    && a["at"]["row"].is_u64()
                    && a["at"]["col"].is_u64()
            }));
            // The goal is in view whenever an action is chosen: at most half the
            // workspace's side inside its edge.
            let half_side = f64::from(sim::workspace::SIDE) / 2.0 + 1e-4;
            assert!(actions.iter().all(|a| {
                a["goal_inside_edge"]
                    .as_f64()
                    .is_some_and(|inside| inside <= half_side)
            }));
        }
    }
    // The average is the paper's "challenging" column: the arrangements, not random scenes.
    assert_eq!(first["average"]["completion"], cases[0]["completion"]);

    // An ensemble of the checkpoint with itself averages equal Q maps: the same runs.
    let doubled = eval("1", &["--ensemble", checkpoint]);
    assert_eq!(doubled["cases"], first["cases"]);
    assert_eq!(doubled["ensemble"][0], checkpoint);

    // --set policy.q_star replaces the config's threshold: below every Q each run opens
    // with a grasp, above every Q with a push.
    let first_actions = |q_star: &str| -> Vec<Value> {
        let report = eval("1", &["--set", &format!("policy.q_star={q_star}")]);
        assert_eq!(
            report["q_star"].as_f64().unwrap(),
            q_star.parse::<f64>().unwrap()
        );
        let firsts: Vec<Value> = std::fs::read_to_string(&runs_json)
            .unwrap()
            .lines()
            .map(|line| {
                serde_json::from_str::<Value>(line).unwrap()["actions"][0]["primitive"].clone()
            })
            .collect();
        assert!(!firsts.is_empty(), "no run in {}", runs_json.display());
        firsts
    };
    assert!(first_actions("-1000").iter().all(|p| p == "grasp"));
    assert!(first_actions("1000").iter().all(|p| p == "push"));

    // A free border grasps where Q* would push; once, only until a grasp picks nothing,
    // after which Q* pushes.
    let runs_under = |once: &str| -> Vec<Vec<Value>> {
        eval(
            "1",
            &[
                "--set",
                "policy.q_star=1000",
                "--set",
                "policy.free_border=1",
                "--set",
                &format!("policy.free_border_once={once}"),
            ],
        );
        std::fs::read_to_string(&runs_json)
            .unwrap()
            .lines()
            .map(|line| {
                let run: Value = serde_json::from_str(line).unwrap();
                run["actions"].as_array().unwrap().clone()
            })
            .collect()
    };
    let every_action = |runs: &[Vec<Value>]| runs.iter().flatten().cloned().collect::<Vec<_>>();
    assert!(
        every_action(&runs_under("false"))
            .iter()
            .all(|a| a["primitive"] == "grasp")
    );
    let once = runs_under("true");
    let after_a_failed_grasp: Vec<&Value> = once
        .iter()
        .flat_map(|run| run.windows(2))
        .filter(|pair| pair[0]["primitive"] == "grasp" && pair[0]["grasped"].is_null())
        .map(|pair| &pair[1]["primitive"])
        .collect();
    assert!(!after_a_failed_grasp.is_empty());
    assert!(after_a_failed_grasp.iter().all(|&p| p == "push"));
    // Settings merge, and the report says the policy that acted.
    let margined = eval(
        "1",
        &[
            "--set",
            "policy.grasp_margin=0.02",
            "--set",
            "policy.q_star=1000",
            "--set",
            "policy.goal_guard=0.02",
            "--set",
            "sim.guarded_push_descent=true",
            "--set",
            "policy.free_border=0.25",
            "--set",
            "policy.free_border_once=true",
            "--set",
            "policy.landing_guard=0.004",
            "--set",
            "policy.landing_subpixels=3",
            "--set",
            "policy.landing_retreat=0.008",
            "--set",
            "policy.grasp_landing_guard=0.002",
            "--set",
            "policy.squeeze_guard=0.5",
            "--set",
            "policy.view_edge_guard=true",
            "--avoid-failed-grasps",
            "--grasp-after-idle-push",
        ],
    );
    assert_eq!(
        (
            margined["grasp_margin"].as_f64().unwrap(),
            margined["q_star"].as_f64().unwrap(),
            margined["goal_guard"].as_f64(),
            margined["guarded_push_descent"].as_bool(),
            margined["free_border"].as_f64(),
            margined["free_border_once"].as_bool(),
            margined["landing_guard"].as_f64(),
            margined["landing_subpixels"].as_u64(),
            margined["grasp_landing_guard"].as_f64(),
            margined["squeeze_guard"].as_f64(),
            margined["avoid_failed_grasps"].as_bool(),
            margined["grasp_after_idle_push"].as_bool()
        ),
        (
            0.02,
            1000.0,
            Some(0.02),
            Some(true),
            Some(0.25),
            Some(true),
            Some(0.004),
            Some(3),
            Some(0.002),
            Some(0.5),
            Some(true),
            Some(true)
        )
    );
    assert_eq!(margined["view_edge_guard"].as_bool(), Some(true));
    assert_eq!(margined["landing_retreat"].as_f64(), Some(0.008));
    // The shipped test-time settings as one file, and --set on top of it.
    let file: toml::Table =
        toml::from_str(&std::fs::read_to_string("configs/test-time.toml").unwrap()).unwrap();
    let shipped = eval(
        "1",
        &[
            "--settings",
            "configs/test-time.toml",
            "--set",
            "policy.goal_guard=0.03",
        ],
    );
    let policy = file["policy"].as_table().unwrap();
    assert!(policy.len() >= 8, "{policy:?}");
    for (key, value) in policy {
        let got = &shipped[key.as_str()];
        match value {
            toml::Value::Float(want) => {
                let want = if key == "goal_guard" { 0.03 } else { *want };
                let got = got.as_f64().unwrap_or(f64::NAN);
                assert!((got - want).abs() < 1e-6, "{key}: {got}, not {want}");
            }
            toml::Value::Boolean(want) => assert_eq!(got.as_bool(), Some(*want), "{key}"),
            toml::Value::Integer(want) => assert_eq!(got.as_i64(), Some(*want), "{key}"),
            other => panic!("{key} = {other}: a kind of value this test does not read"),
        }
    }

    // The authors' protocol: their rule and Q*, random scenes by the Q* alone, and learning
    // during the test. A stage-1 checkpoint trains its grasp net alone, so each grasp with a
    // decision after it takes one update; the why-report covers every run.
    let authors = eval("1", &["--learn", "--authors-rule", "--why"]);
    assert_eq!(
        (
            authors["rule"].as_str(),
            authors["random_scene_rule"].as_str(),
            authors["q_star"].as_f64()
        ),
        (Some("threshold-or-crowded"), Some("threshold"), Some(1.5)),
        "{authors}"
    );
    assert_eq!(authors["learning"]["trained"], serde_json::json!(["grasp"]));
    for case in authors["cases"].as_array().unwrap() {
        assert_eq!(case["why"]["runs"], 2, "{case}");
        if case["complete_runs"].as_u64().unwrap() > 0 {
            // Any object picked counts at least as often as the goal.
            assert!(
                case["any_object_grasp_success"].as_f64().unwrap()
                    >= case["grasp_success"].as_f64().unwrap(),
                "{case}"
            );
        }
    }
    for line in std::fs::read_to_string(&runs_json).unwrap().lines() {
        let run: Value = serde_json::from_str(line).unwrap();
        let actions = run["actions"].as_array().unwrap();
        let labelled_grasps = actions[..actions.len() - 1]
            .iter()
            .filter(|a| a["primitive"] == "grasp")
            .count();
        assert_eq!(run["updates"], labelled_grasps, "{run}");
        assert!(
            actions
                .iter()
                .all(|a| a["goal_border_occupancy"].is_number())
        );
    }
    assert!(first["learning"].is_null() && first["cases"][0]["why"].is_null());

    // The table says the same in words, with `flag`; goal-agnostic runs clear the table.
    let table_with = |flag: &str| {
        pushgrasp_ok(&[
            "eval",
            "--checkpoint",
            checkpoint,
            "--arrangements",
            "configs/arrangements/challenging-05.toml",
            "--runs",
            "1",
            flag,
        ])
    };
    let table = table_with("--goal-agnostic");
    assert!(
        table.contains("completion")
            && table.contains("arrangements avg")
            && table.contains("goal-agnostic"),
        "{table}"
    );
    let why = table_with("--why");
    assert!(
        why.contains("any object picked")
            && why.contains("why runs failed, arrangements: 1 runs")
            && why.contains("picked the goal"),
        "{why}"
    );

    // The same checkpoint's grasp net scored against every direct grasp of the goal, in a
    // case where some grasps pick it every time and some never do.
    let grasps: Value = serde_json::from_str(&pushgrasp_ok(&[
        "scene",
        "grasps",
        "--arrangements",
        "configs/arrangements/challenging-00.toml",
        "--stride",
        "4",
        "--jitters",
        "1",
        "--checkpoint",
        checkpoint,
        "--json",
    ]))
    .unwrap();
    let case = &grasps["cases"][0];
    assert!(
        (0.0..=1.0).contains(&case["net_auc"].as_f64().unwrap()),
        "{grasps}"
    );
    // One try per grasp: the best-scored grasp picked the goal or it did not.
    let best = case["net_best"].as_f64().unwrap();
    assert!(best == 0.0 || best == 1.0, "{grasps}");

    // One case: its average is the case itself.
    assert_eq!(grasps["average"]["net_best"], case["net_best"], "{grasps}");
    assert_eq!(grasps["net_auc_target"], 0.85, "{grasps}");

    // The grasp ranking on one packed cluster the net never trained on, one try per grasp.
    let ranking: Value = serde_json::from_str(&pushgrasp_ok(&[
        "scene",
        "grasps",
        "--random",
        "1",
        "--objects",
        "5",
        "--row",
        "4",
        "--lines",
        "2",
        "--jitters",
        "1",
        "--checkpoint",
        checkpoint,
        "--json",
    ]))
    .unwrap();
    assert_eq!(ranking["cases"].as_array().unwrap().len(), 1, "{ranking}");
    let average = &ranking["average"];
    assert!(
        average["net_auc"].is_null() || (0.0..=1.0).contains(&average["net_auc"].as_f64().unwrap())
    );
    let top1 = average["net_best"].as_f64().unwrap();
    assert!(top1 == 0.0 || top1 == 1.0, "{ranking}");
    // The top five grasps, one try each: a count of five.
    let top5 = average["net_top_k"].as_f64().unwrap() * 5.0;
    assert!(
        (top5 - top5.round()).abs() < 1e-9 && (0.0..=5.0).contains(&top5),
        "{ranking}"
    );
    assert!((0.0..=1.0).contains(&average["success"].as_f64().unwrap()));

    // Nothing to test, and a checkpoint that is not one, are refused with the reason.
    let none = pushgrasp_fails(&["eval", "--checkpoint", checkpoint]);
    assert!(none.contains("nothing to test"), "{none}");
    let missing = Path::new(logs_dir).join("eval/no-such-checkpoint");
    let err = pushgrasp_fails(&[
        "eval",
        "--checkpoint",
        missing.to_str().unwrap(),
        "--random",
        "6",
    ]);
    assert!(err.contains("no-such-checkpoint"), "{err}");
    let err = pushgrasp_fails(&[
        "eval",
        "--checkpoint",
        checkpoint,
        "--ensemble",
        missing.to_str().unwrap(),
        "--random",
        "6",
    ]);
    assert!(err.contains("no-such-checkpoint"), "{err}");
    // The checkpoint's random scenes with `more` arguments, which must be refused.
    let refused = |more: &[&str]| {
        let mut args = vec!["eval", "--checkpoint", checkpoint, "--random", "6"];
        args.extend(more);
        pushgrasp_fails(&args)
    };
    // A bad setting is refused naming the config, --set and the field.
    let err = refused(&["--set", "policy.grasp_margin=-0.01"]);
    assert!(
        err.contains("config.toml with --set") && err.contains("policy.grasp_margin"),
        "{err}"
    );
    // A settings file is refused naming the file: with a bad value, the field; with bad
    // TOML, the line.
    let bad_value = logs.path().join("bad-value.toml");
    std::fs::write(&bad_value, "[policy]\nsqueeze_guard = -1.0\n").unwrap();
    let err = refused(&["--settings", bad_value.to_str().unwrap()]);
    assert!(
        err.contains("--settings")
            && err.contains("bad-value.toml")
            && err.contains("squeeze_guard"),
        "{err}"
    );
    let bad_toml = logs.path().join("bad-toml.toml");
    std::fs::write(&bad_toml, "[policy]\ngoal_guard = \n").unwrap();
    let err = refused(&["--settings", bad_toml.to_str().unwrap()]);
    assert!(
        err.contains("bad-toml.toml") && err.contains("line 2"),
        "{err}"
    );
    // A goal-agnostic test has no labels to learn from.
    let err = refused(&["--goal-agnostic", "--learn"]);
    assert!(
        err.contains("--goal-agnostic") && err.contains("--learn"),
        "{err}"
    );
}
