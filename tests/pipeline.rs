//! `pushgrasp pipeline` end to end on a tiny budget: three stages in order, the first from
//! trunks `pushgrasp pretrain` wrote and each other from the previous stage's checkpoint, the
//! last training two nets (an ensemble's members), a `[set]` that switches parts of the
//! method off in every stage, a second start that skips what finished, and `inspect` joining
//! the stages.

use std::process::Command;

use serde_json::Value;

/// A `pushgrasp` command with `args`, run from the project's root; its standard output, once
/// it succeeded.
fn pushgrasp(args: impl FnOnce(&mut Command) -> &mut Command) -> String {
    let mut command = Command::new(env!("CARGO_BIN_EXE_pushgrasp"));
    let output = args(&mut command)
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

fn pipeline(file: &std::path::Path, logs: &std::path::Path) -> String {
    pushgrasp(|c| {
        c.arg("pipeline")
            .arg("--config")
            .arg(file)
            .arg("--logs")
            .arg(logs)
            .args(["--id", "smoke", "--threads"])
    })
}

#[test]
fn the_stages_run_in_order_from_each_others_checkpoints() {
    let work = tempfile::tempdir().unwrap();
    let configs = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    let file = work.path().join("pipeline.toml");
    // The second stage ends on a learner-update budget alone (no episode budget); the last
    // trains two nets, an ensemble's members.
    let stages: String = [(1, 10, "", 1), (2, 0, "updates = 2\n", 1), (3, 4, "", 2)]
        .iter()
        .map(|(n, episodes, updates, members)| {
            format!(
                "[[stages]]\nconfig = {:?}\nepisodes = {episodes}\n{updates}members = {members}\n",
                configs.join(format!("stage{n}.toml"))
            )
        })
        .collect();
    let pretrained = work.path().join("pretrained");
    pushgrasp(|c| {
        c.arg("pretrain")
            .arg("--config")
            .arg(configs.join("stage1.toml"))
            .arg("--out")
            .arg(&pretrained)
            .args(["--scenes", "2", "--steps", "2", "--batch", "1"])
    });
    // The ablation switches, as configs/ablations/ use them, the first stage's start, and
    // the learner valuing pushes' next states itself.
    let set = format!(
        "[set]\npush_reward = \"none\"\nbuffer.relabel = false\ninit_from = {:?}\n\
         learning.target_update_every = 2\n",
        pretrained
    );
    std::fs::write(&file, format!("{set}{stages}")).unwrap();
    let logs = work.path().join("logs");
    let said = pipeline(&file, &logs);
    assert!(said.contains("pipeline smoke done"), "{said}");

    let dir = logs.join("smoke");
    for (stage, episodes) in [(1, 10), (2, 0), (3, 4)] {
        let run = dir.join(format!("stage{stage}"));
        let summary: Value =
            serde_json::from_slice(&std::fs::read(run.join("summary.json")).unwrap()).unwrap();
        assert!(summary["buffer"]["episodes"].as_u64().unwrap() >= episodes);
        assert_eq!(summary["interrupted"], false);
        let config: toml::Table =
            toml::from_str(&std::fs::read_to_string(run.join("config.toml")).unwrap()).unwrap();
        if stage == 2 {
            assert_eq!(config["episodes"].as_integer(), Some(0));
            assert_eq!(config["updates"].as_integer(), Some(2));
            assert!(summary["learner"]["updates"].as_u64().unwrap() >= 2);
        }
        assert_eq!(config["stage"].as_integer(), Some(stage));
        assert_eq!(config["push_reward"].as_str(), Some("none"));
        assert_eq!(config["buffer"]["relabel"].as_bool(), Some(false));
        assert_eq!(
            summary["buffer"]["relabelled"], 0,
            "relabelling is off in stage {stage}"
        );
        // Stage 1 has no pushes; stage 2 learns from nothing else, each push stored with its
        // next step (an episode ends with a grasp), so each update values several.
        let learned = summary["learner"]["learned_next_values"].as_u64().unwrap();
        let updates = summary["learner"]["updates"].as_u64().unwrap();
        match stage {
            1 => assert_eq!(learned, 0),
            2 => assert!(learned >= updates, "{learned} values, {updates} updates"),
            _ => {}
        }
        assert!(
            dir.join(format!("stage{stage}.toml")).exists(),
            "the resolved config"
        );
        let init = config.get("init_from").and_then(|v| v.as_str());
        if stage == 1 {
            assert_eq!(init.map(std::path::PathBuf::from), Some(pretrained.clone()));
        } else {
            let previous = dir.join(format!("stage{}/checkpoint", stage - 1));
            assert_eq!(
                init.map(std::path::PathBuf::from),
                Some(std::fs::canonicalize(previous).unwrap())
            );
        }
    }

    // Stage 3's second net: the same start, a seed of its own; the two tested as one.
    let second = dir.join("stage3-member2");
    let config = |run: &str| -> toml::Table {
        toml::from_str(&std::fs::read_to_string(dir.join(run).join("config.toml")).unwrap())
            .unwrap()
    };
    let (first_config, second_config) = (config("stage3"), config("stage3-member2"));
    assert_eq!(
        second_config["seed"].as_integer().unwrap(),
        first_config["seed"].as_integer().unwrap() + 1000
    );
    assert_eq!(second_config["init_from"], first_config["init_from"]);
    assert!(second.join("summary.json").exists());
    assert!(
        said.contains(&format!(
            "--checkpoint {} --ensemble {} --settings configs/test-time.toml",
            dir.join("stage3/checkpoint").display(),
            second.join("checkpoint").display()
        )),
        "{said}"
    );

    // Started again, it finds every run done.
    let again = pipeline(&file, &logs);
    assert_eq!(
        again.matches("finished before, skipped").count(),
        4,
        "{again}"
    );

    // inspect reads the pipeline directory as its three stages and joins them in one line.
    let plot = work.path().join("curves.svg");
    let inspect = pushgrasp(|c| {
        c.arg("inspect")
            .arg(&dir)
            .arg("--json")
            .arg("--plot")
            .arg(&plot)
    });
    let reports: Value = serde_json::from_str(&inspect).unwrap();
    let names: Vec<&str> = reports
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["run"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["smoke/stage1", "smoke/stage2", "smoke/stage3"]);
    for r in reports.as_array().unwrap() {
        let actions = r["actions"].as_u64().unwrap();
        assert!(
            actions >= r["episodes"].as_u64().unwrap(),
            "an episode takes an action"
        );
    }
    let svg = std::fs::read_to_string(&plot).unwrap();
    assert!(
        svg.lines().any(|l| l == "smoke"),
        "one line labelled by the pipeline"
    );
    assert!(
        !svg.lines().any(|l| l == "smoke/stage2"),
        "not one per stage"
    );
}
