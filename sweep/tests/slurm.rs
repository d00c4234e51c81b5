//! The Slurm backend: the job-array script and reading `sacct`/`squeue` output.

use std::path::{Path, PathBuf};
use std::process::Command;

use sweep::{
    Axis, Budget, JobState, RunPlan, SlurmOptions, Sweep, job_array_script, parse_sacct,
    parse_squeue,
};
use toml::Value;

fn sweep_of(axes: Vec<Axis>, slurm: SlurmOptions) -> Sweep {
    Sweep {
        path: PathBuf::from("configs/sweeps/test.toml"),
        name: "stage1-lr".to_string(),
        base_path: PathBuf::from("configs/stage1.toml"),
        base: toml::from_str("actors = 2\nepisodes = 400\n").unwrap(),
        budget: Budget::default(),
        axes,
        slurm,
    }
}

fn seeds(count: i64) -> Axis {
    Axis {
        keys: vec!["seed".to_string()],
        points: (1..=count).map(|seed| vec![Value::Integer(seed)]).collect(),
    }
}

fn options() -> SlurmOptions {
    SlurmOptions {
        partition: Some("gpu".to_string()),
        time: Some("02:00:00".to_string()),
        mem: Some("8G".to_string()),
        cpus_per_task: None,
        max_parallel: Some(4),
        extra: vec!["--gres=gpu:1".to_string()],
    }
}

fn script(sweep: &Sweep, runs: &[RunPlan], dir: &Path) -> String {
    job_array_script(
        sweep,
        runs,
        dir,
        "pushgrasp sweep run-one --sweep-dir {sweep_dir} --run {run_id}",
    )
    .unwrap()
}

fn sbatch_lines(script: &str) -> Vec<&str> {
    script
        .lines()
        .filter_map(|line| line.strip_prefix("#SBATCH "))
        .collect()
}

#[test]
fn script_has_the_array_resources_and_run_ids() {
    let sweep = sweep_of(vec![seeds(12)], options());
    let runs = sweep.expand();
    let text = script(&sweep, &runs, Path::new("/scratch/sweeps/stage1-lr"));
    assert!(text.starts_with("#!/bin/bash\n"));
    assert_eq!(
        sbatch_lines(&text),
        [
            "--job-name=stage1-lr",
            "--array=0-11%4",
            "--partition=gpu",
            "--time=02:00:00",
            "--mem=8G",
            "--cpus-per-task=4",
            "--output=\"/scratch/sweeps/stage1-lr/slurm/%A_%a.out\"",
            "--gres=gpu:1",
        ]
    );
    assert!(text.contains("set -euo pipefail\n"));
    assert!(text.contains("RUNS=(\n  'stage1-lr-00'\n  'stage1-lr-01'\n"));
    assert!(text.contains("  'stage1-lr-11'\n)\n"));
    assert!(text.contains("RUN_ID=${RUNS[$SLURM_ARRAY_TASK_ID]}\n"));
    assert!(text.ends_with(
        "pushgrasp sweep run-one --sweep-dir '/scratch/sweeps/stage1-lr' --run \"$RUN_ID\"\n"
    ));
}

#[test]
fn cpus_default_to_the_most_actors_plus_two() {
    let actors = Axis {
        keys: vec!["actors".to_string()],
        points: vec![vec![Value::Integer(6)], vec![Value::Integer(2)]],
    };
    let slurm = SlurmOptions::default();
    let sweep = sweep_of(vec![actors], slurm.clone());
    let text = script(&sweep, &sweep.expand(), Path::new("/s"));
    assert!(sbatch_lines(&text).contains(&"--cpus-per-task=8"));
    assert!(sbatch_lines(&text).contains(&"--array=0-1"));

    let fixed = sweep_of(
        vec![seeds(2)],
        SlurmOptions {
            cpus_per_task: Some(3),
            ..slurm
        },
    );
    let text = script(&fixed, &fixed.expand(), Path::new("/s"));
    assert!(sbatch_lines(&text).contains(&"--cpus-per-task=3"));
}

#[test]
fn runs_without_actors_need_cpus_per_task() {
    let mut sweep = sweep_of(vec![seeds(2)], SlurmOptions::default());
    sweep.base.remove("actors");
    let error = job_array_script(&sweep, &sweep.expand(), Path::new("/s"), "true")
        .unwrap_err()
        .to_string();
    assert!(error.contains("cpus_per_task"), "{error}");
    assert!(error.contains("stage1-lr-0"), "{error}");
}

#[test]
fn no_runs_is_an_error() {
    let sweep = sweep_of(vec![seeds(1)], options());
    assert!(job_array_script(&sweep, &[], Path::new("/s"), "true").is_err());
}

const AWKWARD: &str = "/data/my sweeps/it's #1 at 100%";

#[test]
fn awkward_sweep_dir_is_quoted_for_sbatch_and_bash() {
    let sweep = sweep_of(vec![seeds(3)], options());
    let text = script(&sweep, &sweep.expand(), Path::new(AWKWARD));
    assert!(
        sbatch_lines(&text)
            .contains(&r#"--output="/data/my sweeps/it\'s \#1 at 100%%/slurm/%A_%a.out""#),
        "{text}"
    );
    assert!(
        text.contains(r"--sweep-dir '/data/my sweeps/it'\''s #1 at 100%' --run"),
        "{text}"
    );
}

/// Runs the rendered script with bash as array task 1, its command printing its arguments:
/// they must arrive as the run id and the sweep directory, each one word.
#[test]
fn rendered_script_is_valid_bash_passing_the_right_words() {
    if Command::new("bash").arg("--version").output().is_err() {
        eprintln!("no bash here: skipping");
        return;
    }
    let sweep = sweep_of(vec![seeds(3)], options());
    let text = job_array_script(
        &sweep,
        &sweep.expand(),
        Path::new(AWKWARD),
        "printf '<%s>\\n' {run_id} {sweep_dir}",
    )
    .unwrap();
    let dir = tempfile::TempDir::new().unwrap();
    let path = dir.path().join("job.sh");
    std::fs::write(&path, &text).unwrap();

    let check = Command::new("bash").arg("-n").arg(&path).output().unwrap();
    assert!(check.status.success(), "bash -n: {check:?}\n{text}");

    let run = Command::new("bash")
        .arg(&path)
        .env("SLURM_ARRAY_TASK_ID", "1")
        .output()
        .unwrap();
    assert!(run.status.success(), "{run:?}\n{text}");
    assert_eq!(
        String::from_utf8(run.stdout).unwrap(),
        format!("<stage1-lr-1>\n<{AWKWARD}>\n")
    );

    // Outside an array task the script stops instead of running with no run id.
    let outside = Command::new("bash")
        .arg(&path)
        .env_remove("SLURM_ARRAY_TASK_ID")
        .output()
        .unwrap();
    assert!(!outside.status.success());
}

#[test]
fn sweep_dirs_no_sbatch_line_can_hold_are_rejected() {
    let sweep = sweep_of(vec![seeds(1)], options());
    for dir in ["/a\nb", r"/a\b"] {
        assert!(job_array_script(&sweep, &sweep.expand(), Path::new(dir), "true").is_err());
    }
}

const SACCT: &str = "\
1234_0|COMPLETED
1234_0.batch|COMPLETED
1234_0.extern|COMPLETED
1234_1|FAILED
1234_1.batch|COMPLETED
1234_[2-4]|PENDING
1234_5|CANCELLED by 0
1234_6|RUNNING
1234_6.batch|RUNNING
1234_7|FAILED
1234_8|TIMEOUT
";

#[test]
fn sacct_gives_each_index_its_task_state() {
    let states = parse_sacct(SACCT).unwrap();
    let expected = [
        (0, JobState::Completed),
        (1, JobState::Failed),
        (2, JobState::Pending),
        (3, JobState::Pending),
        (4, JobState::Pending),
        (5, JobState::Cancelled),
        (6, JobState::Running),
        (7, JobState::Failed),
        (8, JobState::Other("TIMEOUT".to_string())),
    ];
    assert_eq!(states.into_iter().collect::<Vec<_>>(), expected);
}

#[test]
fn sacct_ranges_take_lists_and_limits() {
    let states = parse_sacct("1234_[2-4,7%2]|PENDING\n\n1234_9|COMPLETED\n").unwrap();
    assert_eq!(states.keys().copied().collect::<Vec<_>>(), [2, 3, 4, 7, 9]);
    assert_eq!(states[&7], JobState::Pending);
}

#[test]
fn squeue_lines_parse_the_same_way() {
    let states =
        parse_squeue("1234_3|RUNNING\n1234_[4-9%2]|PENDING\n1234_10|COMPLETING\n").unwrap();
    assert_eq!(states.len(), 8);
    assert_eq!(states[&3], JobState::Running);
    assert!((4..=9).all(|i| states[&i] == JobState::Pending));
    assert_eq!(states[&10], JobState::Running);
    assert!(parse_squeue("").unwrap().is_empty());
}

#[test]
fn malformed_lines_are_errors_naming_the_line() {
    for (text, problem) in [
        (
            "1234_0|COMPLETED\n1234_1 COMPLETED\n",
            "expected `<job id>|<state>`",
        ),
        ("1234|COMPLETED\n", "not a job array task"),
        ("1234_x|COMPLETED\n", "not a number"),
        ("1234_[4-2]|PENDING\n", "bad index range"),
        ("1234_[2-4|PENDING\n", "unclosed range"),
        ("1234_0|COMPLETED\n1240_1|COMPLETED\n", "two job arrays"),
    ] {
        let message = parse_sacct(text).unwrap_err().to_string();
        let line = text.lines().count();
        assert!(message.contains(&format!("line {line}")), "{message}");
        assert!(message.contains(problem), "{message}");
    }
}
