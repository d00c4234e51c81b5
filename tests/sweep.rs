//! `pushgrasp sweep` end to end: sweeps of tiny stage-1 runs (1 actor, a dozen episodes, a
//! few seconds each) as real processes in temporary directories, checked through what they
//! write: the dry run and its checks, runs side by side, a stopped and a killed sweep, the
//! summary against the runs' own files, and the Slurm backend (its script always; a real
//! single-node Slurm where one can be started here).

use std::borrow::BorrowMut;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant, SystemTime};

use serde_json::Value;
use tempfile::TempDir;

#[path = "slurm/daemons.rs"]
mod daemons;
#[path = "common/json.rs"]
mod json;
#[path = "common/runs.rs"]
mod runs;
use daemons::Slurm;
use json::{json, u};
use runs::{succeeds, summary};

/// Each run's episode budget.
const EPISODES: u64 = 12;
/// The budget of runs that are stopped or killed while they run, not finished.
const LONG: u64 = 100_000;

fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A temporary directory holding `base.toml`: the shipped stage-1 config with one actor.
fn workspace() -> TempDir {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let text = std::fs::read_to_string(repo().join("configs/stage1.toml")).unwrap();
    let mut base: toml::Table = toml::from_str(&text).unwrap();
    base.insert("actors".into(), toml::Value::Integer(1));
    std::fs::write(
        dir.path().join("base.toml"),
        toml::to_string(&base).unwrap(),
    )
    .unwrap();
    dir
}

/// Writes the sweep file `<name>.toml` over `base.toml`: `episodes` per run, one run per
/// seed, then `extra` (more axes, a [slurm] section).
fn sweep_file(dir: &Path, name: &str, episodes: u64, seeds: &[u64], extra: &str) {
    let seeds: Vec<String> = seeds.iter().map(u64::to_string).collect();
    std::fs::write(
        dir.join(format!("{name}.toml")),
        format!(
            "name = \"{name}\"\nbase = \"base.toml\"\nbudget = {{ episodes = {episodes} }}\n\n\
             [[axis]]\nkey = \"seed\"\nvalues = [{}]\n{extra}",
            seeds.join(", ")
        ),
    )
    .unwrap();
}

/// `pushgrasp sweep <args>` in `dir`, sweep directories under `dir/logs`.
fn sweep(dir: &Path, args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_pushgrasp"));
    command
        .arg("sweep")
        .args(args)
        .current_dir(dir)
        .env("RUST_BACKTRACE", "0");
    command
}

fn output(command: &mut Command) -> Output {
    command.output().expect("pushgrasp runs")
}

// `succeeds` and `fails` take a `Command` or the `&mut Command` its builder methods return.

/// Runs the command, which must fail; its stderr.
fn fails(mut command: impl BorrowMut<Command>) -> String {
    let command = command.borrow_mut();
    let output = output(command);
    assert!(!output.status.success(), "{command:?} succeeded");
    String::from_utf8_lossy(&output.stderr).into_owned()
}

fn modified(path: &Path) -> SystemTime {
    std::fs::metadata(path)
        .and_then(|m| m.modified())
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Every run's output file in the sweep directory, for a failure's message.
fn outputs(sweep_dir: &Path) -> String {
    let mut files: Vec<PathBuf> = std::fs::read_dir(sweep_dir.join("output"))
        .map(|entries| entries.filter_map(|e| Some(e.ok()?.path())).collect())
        .unwrap_or_default();
    files.sort();
    files
        .iter()
        .map(|path| {
            let text = std::fs::read_to_string(path).unwrap_or_default();
            format!("== {}\n{text}", path.display())
        })
        .collect()
}

/// The episodes a running run has ended, from its launcher's progress records (0 before
/// the first). Waiting for one means every role is up, so a kill lands mid-run (the kills
/// during start-up are tests/startup.rs's).
fn episodes(run_dir: &Path) -> u64 {
    mcaplog::json_messages(run_dir.join("launcher.mcap"), "/launcher/progress")
        .ok()
        .and_then(|records| records.last().map(|r| u(&r["episodes"])))
        .unwrap_or(0)
}

/// Whether process `pid` runs (a zombie, whose command line is empty, does not).
fn alive(pid: &str) -> bool {
    std::fs::read(format!("/proc/{pid}/cmdline")).is_ok_and(|cmdline| !cmdline.is_empty())
}

/// Whether the run lists a live role in its processes file.
fn roles_running(run_dir: &Path) -> bool {
    std::fs::read(run_dir.join("processes.json"))
        .ok()
        .and_then(|bytes| serde_json::from_slice::<Value>(&bytes).ok())
        .and_then(|entries| entries.as_array().cloned())
        .is_some_and(|entries| entries.iter().any(|e| alive(&u(&e["pid"]).to_string())))
}

fn wait_until(what: &str, timeout: Duration, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + timeout;
    while !done() {
        assert!(Instant::now() < deadline, "{what} within {timeout:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn signal(target: &str, signal: &str) {
    let status = Command::new("kill")
        .args([&format!("-{signal}"), "--", target])
        .stderr(Stdio::null())
        .status()
        .expect("kill runs");
    assert!(status.success(), "kill -{signal} {target}");
}

/// A sweep started in the background in a process group of its own, killed with the whole
/// group if the test ends before it does.
struct Background {
    /// Taken by `wait`.
    child: Option<Child>,
}

impl Background {
    fn start(command: &mut Command) -> Self {
        let child = command
            .process_group(0)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("pushgrasp starts");
        Self { child: Some(child) }
    }

    fn pid(&self) -> u32 {
        self.child.as_ref().expect("not waited for").id()
    }

    /// Its process group, as kill(1) names it.
    fn group(&self) -> String {
        format!("-{}", self.pid())
    }

    /// Waits for its end (its output is a few lines: the pipes do not fill); its status and
    /// stderr. On a timeout, the panic shows the runs' output files of `sweep_dir`.
    fn wait(mut self, timeout: Duration, sweep_dir: &Path) -> (std::process::ExitStatus, String) {
        let mut child = self.child.take().expect("waited for once");
        let deadline = Instant::now() + timeout;
        while child.try_wait().unwrap().is_none() {
            if Instant::now() > deadline {
                self.child = Some(child);
                panic!(
                    "the sweep did not end within {timeout:?}; its runs' output:\n{}",
                    outputs(sweep_dir)
                );
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let output = child.wait_with_output().unwrap();
        (
            output.status,
            String::from_utf8_lossy(&output.stderr).into_owned(),
        )
    }
}

impl Drop for Background {
    fn drop(&mut self) {
        if let Some(child) = &mut self.child {
            let _ = Command::new("kill")
                .args(["-KILL", "--", &format!("-{}", child.id())])
                .stderr(Stdio::null())
                .status();
            let _ = child.wait();
        }
    }
}

#[test]
fn dry_run_lists_the_runs_and_checks_their_configs() {
    let logs = tempfile::tempdir().unwrap();
    let logs_arg = logs.path().to_str().unwrap();
    let shipped = [
        "--config",
        "configs/sweeps/stage1-seeds.toml",
        "--logs",
        logs_arg,
    ];
    let listing = succeeds(sweep(repo(), &shipped).arg("--dry-run"));
    for line in [
        "stage1-seeds-0  seed=1",
        "stage1-seeds-1  seed=2",
        "stage1-seeds-2  seed=3",
        "every run's config is valid",
    ] {
        assert!(listing.contains(line), "{line:?} not in\n{listing}");
    }
    let verbose = succeeds(sweep(repo(), &shipped).args(["--dry-run", "--verbose"]));
    let run_1 = verbose
        .split("# stage1-seeds-1\n")
        .nth(1)
        .expect("run 1's resolved config");
    assert!(run_1.contains("seed = 2\n") && run_1.contains("episodes = 400\n"));
    assert!(
        std::fs::read_dir(logs.path()).unwrap().next().is_none(),
        "a dry run wrote to --logs"
    );

    let dir = workspace();
    sweep_file(
        dir.path(),
        "typo",
        EPISODES,
        &[1, 2],
        "\n[[axis]]\nkey = \"learning.lerning_rate\"\nvalues = [0.001]\n",
    );
    let error = fails(sweep(dir.path(), &["--config", "typo.toml", "--dry-run"]));
    for part in [
        "typo.toml",
        "run typo-0",
        "`learning.lerning_rate`",
        "unknown field",
    ] {
        assert!(error.contains(part), "{part:?} not in {error:?}");
    }
    // A value the config refuses: only the second run has it.
    sweep_file(
        dir.path(),
        "zero",
        EPISODES,
        &[1],
        "\n[[axis]]\nkey = \"actors\"\nvalues = [1, 0]\n",
    );
    let error = fails(sweep(dir.path(), &["--config", "zero.toml"]));
    for part in ["run zero-1", "`actors` = 0", "at least 1"] {
        assert!(error.contains(part), "{part:?} not in {error:?}");
    }
    assert!(
        !dir.path().join("logs").exists(),
        "an invalid sweep started"
    );
}

#[test]
fn two_runs_at_once_do_not_cross() {
    let dir = workspace();
    sweep_file(dir.path(), "pair", EPISODES, &[1, 2], "");
    let out = succeeds(sweep(
        dir.path(),
        &["--config", "pair.toml", "--max-parallel", "2"],
    ));
    assert!(out.contains("2 of 2 runs done, 0 failed"), "{out}");
    let sweep_dir = dir.path().join("logs/pair");
    let mut spans = Vec::new();
    for run in ["pair-0", "pair-1"] {
        let summary = summary(&sweep_dir, run);
        assert_eq!(summary["run_id"], run);
        assert_eq!(summary["interrupted"], false);
        let buffer = &summary["buffer"];
        assert!(u(&buffer["episodes"]) >= EPISODES, "{run}: {buffer}");
        // Only its own single actor reached its buffer, and every step it sent arrived.
        let streams = buffer["streams"].as_array().unwrap();
        assert_eq!(streams.len(), 1, "{run}: streams {streams:?}");
        assert_eq!(
            (u(&streams[0]["actor"]), u(&streams[0]["incarnation"])),
            (0, 0)
        );
        assert_eq!(u(&streams[0]["missing"]), 0, "{run} lost steps");
        let reports = summary["actors_reports"].as_array().unwrap();
        assert_eq!(reports.len(), 1);
        assert_eq!(streams[0]["steps"], reports[0]["steps_sent"]);
        assert_eq!(u(&buffer["steps_received"]), u(&streams[0]["steps"]));
        // Its own config: the seed the sweep gave it.
        let config: toml::Table = toml::from_str(
            &std::fs::read_to_string(sweep_dir.join(run).join("config.toml")).unwrap(),
        )
        .unwrap();
        let seed = if run == "pair-0" { 1 } else { 2 };
        assert_eq!(config["seed"].as_integer(), Some(seed));
        let log =
            std::fs::read_to_string(sweep_dir.join("output").join(format!("{run}.log"))).unwrap();
        assert!(log.contains(&format!("run {run}: stage 1")), "{log}");
        spans.push((
            modified(&sweep_dir.join(run).join("config.toml")),
            modified(&sweep_dir.join(run).join("summary.json")),
        ));
    }
    // They ran at the same time: each started before the other ended.
    assert!(
        spans[0].0 < spans[1].1 && spans[1].0 < spans[0].1,
        "the runs did not overlap: {spans:?}"
    );
    let status = succeeds(sweep(dir.path(), &["status", "logs/pair"]));
    assert!(status.contains("2 runs, 2 done"), "{status}");
}

#[test]
fn a_failed_run_is_reported_and_the_others_go_on() {
    let dir = workspace();
    sweep_file(dir.path(), "broken", EPISODES, &[1, 2], "");
    // Make the sweep directory without running anything, then put a file where the second
    // run's directory goes: its `train` fails, the first run's does not.
    let args = ["--config", "broken.toml"];
    succeeds(sweep(dir.path(), &args).args(["--backend", "slurm", "--no-submit"]));
    let sweep_dir = dir.path().join("logs/broken");
    std::fs::write(sweep_dir.join("broken-1"), "in the way").unwrap();
    let output = output(sweep(dir.path(), &args).arg("--resume"));
    let (stdout, stderr) = (
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr),
    );
    assert!(
        !output.status.success(),
        "a sweep with a failed run exited 0"
    );
    assert!(stdout.contains("run broken-1 failed"), "{stdout}");
    assert!(
        stderr.contains("broken-1") && stderr.contains("output/broken-1.log"),
        "{stderr}"
    );
    assert_eq!(summary(&sweep_dir, "broken-0")["interrupted"], false);
    let status = succeeds(sweep(dir.path(), &["status", "logs/broken"]));
    assert!(status.contains("1 done, 1 failed"), "{status}");
}

#[test]
fn sigterm_stops_the_runs_and_resume_is_offered() {
    let dir = workspace();
    sweep_file(dir.path(), "stop", LONG, &[1, 2, 3], "");
    let background = Background::start(&mut sweep(
        dir.path(),
        &["--config", "stop.toml", "--max-parallel", "2"],
    ));
    let sweep_dir = dir.path().join("logs/stop");
    wait_until("both runs under way", Duration::from_secs(60), || {
        episodes(&sweep_dir.join("stop-0")) > 0 && episodes(&sweep_dir.join("stop-1")) > 0
    });
    signal(&background.pid().to_string(), "TERM");
    let (status, stderr) = background.wait(Duration::from_secs(120), &sweep_dir);
    assert!(!status.success(), "a stopped sweep exited 0");
    assert!(
        stderr.contains("SIGTERM") && stderr.contains("--resume"),
        "{stderr}"
    );
    for run in ["stop-0", "stop-1"] {
        // Stopped in order by its own launcher: a summary that says so, nothing left running.
        assert_eq!(summary(&sweep_dir, run)["interrupted"], true, "{run}");
        assert!(!roles_running(&sweep_dir.join(run)), "{run} still runs");
        assert!(
            sweep_dir
                .join(run)
                .join("checkpoint/manifest.toml")
                .exists()
        );
    }
    assert!(
        !sweep_dir.join("stop-2").exists(),
        "a run started after the stop"
    );
    let status = succeeds(sweep(dir.path(), &["status", "logs/stop"]));
    assert!(status.contains("1 not started, 2 unfinished"), "{status}");
}

#[test]
fn a_killed_sweep_resumes_without_rerunning_finished_runs() {
    let dir = workspace();
    // The second run long enough to be caught under way (its progress is seen a second or
    // two late); a zip axis gives each run its seed and its budget.
    let budgets = [EPISODES, 8 * EPISODES, EPISODES];
    std::fs::write(
        dir.path().join("again.toml"),
        format!(
            "name = \"again\"\nbase = \"base.toml\"\n[[axis]]\nzip = [\n  \
             {{ key = \"seed\", values = [1, 2, 3] }},\n  \
             {{ key = \"episodes\", values = {budgets:?} }},\n]\n"
        ),
    )
    .unwrap();
    let args = ["--config", "again.toml", "--max-parallel", "1"];
    let sweep_dir = dir.path().join("logs/again");
    let background = Background::start(&mut sweep(dir.path(), &args));
    wait_until(
        "the first run finished and the second under way",
        Duration::from_secs(120),
        || {
            sweep_dir.join("again-0/summary.json").exists()
                && episodes(&sweep_dir.join("again-1")) > 0
        },
    );
    signal(&background.group(), "KILL");
    let (status, _) = background.wait(Duration::from_secs(30), &sweep_dir);
    assert!(!status.success());

    let first = sweep_dir.join("again-0/summary.json");
    let (bytes, time) = (std::fs::read(&first).unwrap(), modified(&first));
    let status = succeeds(sweep(dir.path(), &["status", "logs/again"]));
    for line in [
        "again-0  done",
        "again-1  unfinished",
        "again-2  not started",
    ] {
        assert!(status.contains(line), "{line:?} not in\n{status}");
    }
    let error = fails(sweep(dir.path(), &args));
    assert!(
        error.contains("already exists") && error.contains("--resume"),
        "{error}"
    );

    let out = succeeds(sweep(dir.path(), &args).arg("--resume"));
    assert!(out.contains("3 runs, 2 to run"), "{out}");
    assert_eq!(
        std::fs::read(&first).unwrap(),
        bytes,
        "the finished run ran again"
    );
    assert_eq!(
        modified(&first),
        time,
        "the finished run's summary was rewritten"
    );
    for (run, budget) in ["again-0", "again-1", "again-2"].into_iter().zip(budgets) {
        let summary = summary(&sweep_dir, run);
        assert_eq!(summary["interrupted"], false, "{run}");
        assert!(u(&summary["buffer"]["episodes"]) >= budget, "{run}");
    }
    let resumed = std::fs::read_to_string(sweep_dir.join("output/again-1.log")).unwrap();
    assert!(
        resumed.contains("starting run again-1") && resumed.contains("resuming run again-1"),
        "{resumed}"
    );
    let fresh = std::fs::read_to_string(sweep_dir.join("output/again-2.log")).unwrap();
    assert!(!fresh.contains("resuming"), "{fresh}");
}

/// Goal grasp success over the last 30 episodes of a run's curve.csv, counted by hand.
fn success_from_curve(run_dir: &Path) -> (usize, f64) {
    let text = std::fs::read_to_string(run_dir.join("curve.csv")).unwrap();
    let grasped: Vec<bool> = text
        .lines()
        .skip(1)
        .map(|line| line.split(',').nth(1).unwrap() == "1")
        .collect();
    let last = &grasped[grasped.len().saturating_sub(30)..];
    let hits = last.iter().filter(|&&g| g).count();
    (grasped.len(), hits as f64 / last.len() as f64)
}

#[test]
fn the_summary_matches_the_runs_files() {
    let dir = workspace();
    sweep_file(dir.path(), "table", EPISODES, &[3, 4], "");
    succeeds(sweep(
        dir.path(),
        &["--config", "table.toml", "--max-parallel", "2"],
    ));
    let sweep_dir = dir.path().join("logs/table");
    let report: Value = serde_json::from_str(&succeeds(sweep(
        dir.path(),
        &["summary", "logs/table", "--json", "--plot", "curves.png"],
    )))
    .unwrap();
    assert_eq!(report["sort"], "success");
    let rows = report["runs"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    let mut successes = Vec::new();
    for row in rows {
        let run = row["run"].as_str().unwrap();
        let summary = summary(&sweep_dir, run);
        let (episodes, by_hand) = success_from_curve(&sweep_dir.join(run));
        assert_eq!(row["state"], "done");
        assert_eq!(row["episodes"], summary["buffer"]["episodes"], "{run}");
        assert_eq!(
            u(&row["episodes"]),
            episodes as u64,
            "{run}: curve.csv rows"
        );
        assert_eq!(row["wall_s"], summary["wall_s"], "{run}");
        let success = row["success_last30"].as_f64().unwrap();
        assert_eq!(
            success,
            summary["buffer"]["success_last30"].as_f64().unwrap()
        );
        assert!(
            (success - by_hand).abs() < 1e-12,
            "{run}: {success} vs {by_hand}"
        );
        // Fewer than 30 episodes: 80% over the last 30 cannot have been reached.
        assert!(episodes < 30 && row["episodes_to_80"].is_null());
        let seed = if run == "table-0" { 3 } else { 4 };
        assert_eq!(row["values"]["seed"], seed);
        successes.push(success);
    }
    assert!(
        successes[0] >= successes[1],
        "not by success: {successes:?}"
    );
    // The two seeds form one group: mean and sample standard deviation, by hand.
    let group = &report["groups"][0];
    assert_eq!(report["groups"].as_array().unwrap().len(), 1);
    assert_eq!(group["done"], 2);
    let mean = (successes[0] + successes[1]) / 2.0;
    let spread = (successes[0] - successes[1]).abs() / 2f64.sqrt();
    let stat = &group["success_last30"];
    assert!(
        (stat["mean"].as_f64().unwrap() - mean).abs() < 1e-12,
        "{stat}"
    );
    assert!(
        (stat["spread"].as_f64().unwrap() - spread).abs() < 1e-12,
        "{stat}"
    );
    assert_eq!(group["reached_80"], 0);
    let png = std::fs::read(dir.path().join("curves.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG"), "--plot wrote no PNG");

    let text = succeeds(sweep(
        dir.path(),
        &["summary", "logs/table", "--sort", "run"],
    ));
    let first = text.find("table-0").expect("run table-0 listed");
    let second = text.find("table-1").expect("run table-1 listed");
    assert!(first < second, "--sort run is not in sweep order:\n{text}");
    assert!(
        text.contains("over seeds") && text.contains(&format!("{:.1}%", 100.0 * mean)),
        "{text}"
    );
}

#[test]
fn the_slurm_script_names_every_run_and_runs_one() {
    let dir = workspace();
    sweep_file(
        dir.path(),
        "script",
        EPISODES,
        &[1, 2, 3],
        "\n[slurm]\ncpus_per_task = 1\nmax_parallel = 2\n",
    );
    let out = succeeds(sweep(
        dir.path(),
        &[
            "--config",
            "script.toml",
            "--backend",
            "slurm",
            "--no-submit",
            "--max-parallel",
            "1",
        ],
    ));
    assert!(
        out.contains("sweep.sbatch") && out.contains("3 array tasks"),
        "{out}"
    );
    let sweep_dir = dir.path().join("logs/script");
    let script_path = sweep_dir.join("sweep.sbatch");
    let script = std::fs::read_to_string(&script_path).unwrap();
    let check = Command::new("bash")
        .arg("-n")
        .arg(&script_path)
        .output()
        .unwrap();
    assert!(
        check.status.success(),
        "bash -n: {}",
        String::from_utf8_lossy(&check.stderr)
    );
    // --max-parallel overrides the file's limit.
    assert!(script.contains("#SBATCH --array=0-2%1\n"), "{script}");
    assert!(
        script.contains("RUNS=(\n  'script-0'\n  'script-1'\n  'script-2'\n)\n"),
        "{script}"
    );
    let absolute = std::fs::canonicalize(&sweep_dir).unwrap();
    assert!(
        script.contains(&format!("--logs '{}'", absolute.display())),
        "{script}"
    );
    let state = json(&sweep_dir.join("sweep.json"));
    assert_eq!(state["backend"], "slurm");
    assert!(
        state["slurm"].is_null(),
        "a job recorded without submitting"
    );

    // The script's task, run as Slurm would run array task 1 (from another directory).
    let task = Command::new("bash")
        .arg(&script_path)
        .env("SLURM_ARRAY_TASK_ID", "1")
        .current_dir(std::env::temp_dir())
        .output()
        .unwrap();
    assert!(
        task.status.success(),
        "task 1: {}",
        String::from_utf8_lossy(&task.stderr)
    );
    assert!(u(&summary(&sweep_dir, "script-1")["buffer"]["episodes"]) >= EPISODES);
    assert!(!sweep_dir.join("script-0").exists() && !sweep_dir.join("script-2").exists());
}

#[test]
fn a_sweep_runs_as_a_job_array_on_a_real_slurm() {
    let Some(slurm) = Slurm::start(1) else {
        return;
    };
    let dir = workspace();
    sweep_file(
        dir.path(),
        "array",
        EPISODES,
        &[1, 2],
        "\n[slurm]\ncpus_per_task = 1\n",
    );
    let with_slurm = |args: &[&str]| {
        let mut command = sweep(dir.path(), args);
        command.env("SLURM_CONF", &slurm.conf);
        command
    };
    let out = succeeds(with_slurm(&[
        "--config",
        "array.toml",
        "--backend",
        "slurm",
    ]));
    assert!(out.contains("submitted job array"), "{out}");
    let sweep_dir = dir.path().join("logs/array");
    let job = json(&sweep_dir.join("sweep.json"))["slurm"]["job_id"]
        .as_str()
        .expect("the job id recorded")
        .to_string();
    let mut status = String::new();
    wait_until("both array tasks done", Duration::from_secs(300), || {
        status = succeeds(with_slurm(&["status", "logs/array"]));
        status.contains("2 runs, 2 done")
    });
    assert!(status.contains(&format!("job array {job}")), "{status}");
    for task in 0..2 {
        assert!(
            sweep_dir.join(format!("slurm/{job}_{task}.out")).exists(),
            "task {task}'s output"
        );
    }
    let report: Value =
        serde_json::from_str(&succeeds(with_slurm(&["summary", "logs/array", "--json"]))).unwrap();
    for row in report["runs"].as_array().unwrap() {
        assert_eq!(row["state"], "done", "{row}");
        assert!(u(&row["episodes"]) >= EPISODES, "{row}");
    }
}
