//! `pushgrasp eval` on a checkpoint of a short real run: the paper's table as JSON, the same
//! figures for the same seed, and clear errors for what cannot be tested.

use std::path::Path;
use std::process::{Command, Output};

use serde_json::Value;

fn pushgrasp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pushgrasp"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("pushgrasp runs")
}

fn ok(args: &[&str]) -> String {
    let output = pushgrasp(args);
    assert!(
        output.status.success(),
        "pushgrasp {args:?}:\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout).into_owned()
}

#[test]
fn eval_scores_a_checkpoint_the_same_way_for_the_same_seed() {
    let logs = tempfile::tempdir().unwrap();
    let logs_dir = logs.path().to_str().unwrap();
    ok(&[
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
    let eval = |seed: &str| -> Value {
        serde_json::from_str(&ok(&[
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
        ]))
        .unwrap()
    };
    let first = eval("1");
    assert_eq!(first, eval("1"), "same checkpoint, same seed, same figures");
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
    }
    // The average is the paper's "challenging" column: the arrangements, not random scenes.
    assert_eq!(first["average"]["completion"], cases[0]["completion"]);

    // The table says the same in words; goal-agnostic runs clear the table.
    let table = ok(&[
        "eval",
        "--checkpoint",
        checkpoint,
        "--arrangements",
        "configs/arrangements/challenging-05.toml",
        "--runs",
        "1",
        "--goal-agnostic",
    ]);
    assert!(
        table.contains("completion")
            && table.contains("arrangements avg")
            && table.contains("goal-agnostic"),
        "{table}"
    );

    // Nothing to test, and a checkpoint that is not one, are refused with the reason.
    let none = pushgrasp(&["eval", "--checkpoint", checkpoint]);
    assert!(!none.status.success());
    assert!(String::from_utf8_lossy(&none.stderr).contains("nothing to test"));
    let missing = Path::new(logs_dir).join("eval/no-such-checkpoint");
    let bad = pushgrasp(&[
        "eval",
        "--checkpoint",
        missing.to_str().unwrap(),
        "--random",
        "6",
    ]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success() && err.contains("no-such-checkpoint"),
        "{err}"
    );
}
