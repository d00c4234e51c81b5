//! `pushgrasp pipeline` end to end on a tiny budget: three stages in order, each starting
//! from the previous stage's checkpoint, and a second start that skips what finished.

use std::process::Command;

use serde_json::Value;

fn pipeline(file: &std::path::Path, logs: &std::path::Path) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_pushgrasp"))
        .arg("pipeline")
        .arg("--config")
        .arg(file)
        .arg("--logs")
        .arg(logs)
        .args(["--id", "smoke", "--threads"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("pushgrasp runs");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout).into_owned()
}

#[test]
fn the_stages_run_in_order_from_each_others_checkpoints() {
    let work = tempfile::tempdir().unwrap();
    let configs = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    let file = work.path().join("pipeline.toml");
    let stages: String = [(1, 10), (2, 4), (3, 4)]
        .iter()
        .map(|(n, episodes)| {
            format!(
                "[[stages]]\nconfig = {:?}\nepisodes = {episodes}\n",
                configs.join(format!("stage{n}.toml"))
            )
        })
        .collect();
    std::fs::write(&file, stages).unwrap();
    let logs = work.path().join("logs");
    let said = pipeline(&file, &logs);
    assert!(said.contains("pipeline smoke done"), "{said}");

    let dir = logs.join("smoke");
    for (stage, episodes) in [(1, 10), (2, 4), (3, 4)] {
        let run = dir.join(format!("stage{stage}"));
        let summary: Value =
            serde_json::from_slice(&std::fs::read(run.join("summary.json")).unwrap()).unwrap();
        assert!(summary["buffer"]["episodes"].as_u64().unwrap() >= episodes);
        assert_eq!(summary["interrupted"], false);
        let config: toml::Table =
            toml::from_str(&std::fs::read_to_string(run.join("config.toml")).unwrap()).unwrap();
        assert_eq!(config["stage"].as_integer(), Some(stage));
        let init = config.get("init_from").and_then(|v| v.as_str());
        if stage == 1 {
            assert_eq!(init, None);
        } else {
            let previous = dir.join(format!("stage{}/checkpoint", stage - 1));
            assert_eq!(
                init.map(std::path::PathBuf::from),
                Some(std::fs::canonicalize(previous).unwrap())
            );
        }
    }

    // Started again, it finds every stage done.
    let again = pipeline(&file, &logs);
    assert_eq!(
        again.matches("finished before, skipped").count(),
        3,
        "{again}"
    );
}
