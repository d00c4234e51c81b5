//! `pushgrasp train` end to end: real buffer, learner and actor processes over iceoryx2 (or
//! threads over channels), checked through what the run writes: its summary, the roles'
//! reports, the checkpoint and the buffer snapshot.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use rundir::record::{LAUNCHER_SUMMARY, PROCESS_MEMORY};
use runtime::memory::MemoryRecord;
use serde_json::Value;

#[path = "common/json.rs"]
mod json;
#[path = "common/runs.rs"]
mod runs;
#[path = "common/stage1.rs"]
mod stage1;
use json::{json, u};
use runs::{succeeds, summary};

const CONFIG: &str = "configs/stage1.toml";

fn command(logs: &Path, args: &[&str]) -> Command {
    command_with(Path::new(CONFIG), logs, args)
}

fn command_with(config: &Path, logs: &Path, args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_pushgrasp"));
    command
        .arg("train")
        .arg("--config")
        .arg(config)
        .arg("--logs")
        .arg(logs)
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"));
    command
}

fn train_ok(logs: &Path, args: &[&str]) -> String {
    succeeds(command(logs, args))
}

/// Every step an actor reports sending was received, every stream is gap-free, and the
/// learner trained and checkpointed; returns the steps received.
fn assert_lossless(logs: &Path, run: &str) -> u64 {
    let summary = summary(logs, run);
    let buffer = &summary["buffer"];
    let streams = buffer["streams"].as_array().expect("streams");
    assert!(!streams.is_empty(), "no actor stream reached the buffer");
    for stream in streams {
        assert_eq!(u(&stream["missing"]), 0, "a gap in {stream}");
    }
    // An actor that sent nothing (a slow start, its one step still waiting for the next
    // state when the run ended) opens no stream.
    for report in summary["actors_reports"].as_array().expect("reports") {
        if u(&report["steps_sent"]) == 0 {
            continue;
        }
        let stream = streams
            .iter()
            .find(|s| s["actor"] == report["actor"] && s["incarnation"] == report["incarnation"])
            .unwrap_or_else(|| panic!("no stream for {report}"));
        assert_eq!(
            stream["steps"], report["steps_sent"],
            "sent and received differ for {report}"
        );
    }
    assert!(u(&buffer["priority_updates"]) > 0, "no priority came back");
    let received: u64 = streams.iter().map(|s| u(&s["steps"])).sum();
    assert_eq!(u(&buffer["steps_received"]), received);
    assert!(u(&buffer["episodes"]) > 0);
    assert!(
        u(&summary["learner"]["updates"]) > 0,
        "the learner never trained"
    );
    let dir = logs.join(run);
    assert!(dir.join("checkpoint/manifest.toml").exists());
    assert!(dir.join("buffer.snapshot").exists());
    received
}

/// Waits until the run lists at least `roles` running roles in its processes file.
fn wait_for_processes(logs: &Path, run: &str, roles: usize) -> Vec<Value> {
    let path = logs.join(run).join("processes.json");
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        if let Ok(bytes) = std::fs::read(&path)
            && let Ok(Value::Array(entries)) = serde_json::from_slice::<Value>(&bytes)
            && entries.len() >= roles
        {
            return entries;
        }
        assert!(Instant::now() < deadline, "the run never started its roles");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn wait_exit(child: &mut Child, timeout: Duration) -> std::process::ExitStatus {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(status) = child.try_wait().expect("waitable") {
            return status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("the run did not finish within {timeout:?}");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn logs() -> tempfile::TempDir {
    tempfile::tempdir().expect("a temporary directory")
}

fn pid_of(entries: &[Value], role: &str) -> i32 {
    let entry = entries
        .iter()
        .find(|e| e["role"] == role)
        .unwrap_or_else(|| panic!("no {role} in {entries:?}"));
    u(&entry["pid"]) as i32
}

fn signal(pid: i32, signal: &str) {
    let status = Command::new("kill")
        .args([&format!("-{signal}"), &pid.to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success(), "kill -{signal} {pid}");
}

#[test]
fn two_actor_processes_over_shared_memory_lose_no_step() {
    let logs = logs();
    let out = train_ok(
        logs.path(),
        &["--actors", "2", "--episodes", "16", "--run-id", "shm"],
    );
    let summary = summary(logs.path(), "shm");
    assert_eq!(summary["actors_reports"].as_array().unwrap().len(), 2);
    assert!(assert_lossless(logs.path(), "shm") >= 16);
    assert_cpu_times(&summary, true);
    assert_learner_busy(&summary);
    assert!(out.contains("a busy second)"), "{out}");
}

/// 64 actors: more than the shared-memory limits of a fixed size admitted (every actor past
/// the 60th crash-looped); the services sized from the run take them all.
#[test]
fn sixty_four_actor_processes_meet_their_budget_and_lose_nothing() {
    let _turn = one_at_a_time();
    let logs = logs();
    let printed = train_ok(
        logs.path(),
        &["--actors", "64", "--episodes", "128", "--run-id", "wide"],
    );
    assert!(printed.contains("67 processes, shared memory"), "{printed}");
    let summary = summary(logs.path(), "wide");
    assert_eq!(u(&summary["restarts"]), 0, "{}", summary["faults"]);
    assert_eq!(summary["actors_reports"].as_array().unwrap().len(), 64);
    assert!(u(&summary["buffer"]["episodes"]) >= 128);
    assert_lossless(logs.path(), "wide");
}

/// Four environments to an actor process (`envs_per_actor`): each plays as an actor process
/// of its own would, with its own report, episodes and gap-free stream of steps, while the
/// run holds two actor processes, not eight.
#[test]
fn an_actor_process_steps_several_environments_each_with_its_own_stream() {
    let logs = logs();
    let printed = train_ok(
        logs.path(),
        &[
            "--actors",
            "2",
            "--set",
            "envs_per_actor=4",
            "--episodes",
            "48",
            "--run-id",
            "batched",
        ],
    );
    assert!(printed.contains("2 actors x 4 environments"), "{printed}");
    assert!(printed.contains("5 processes, shared memory"), "{printed}");
    let summary = summary(logs.path(), "batched");
    assert_eq!(u(&summary["restarts"]), 0, "{}", summary["faults"]);
    let reports = summary["actors_reports"].as_array().unwrap();
    let environments: Vec<u64> = reports.iter().map(|r| u(&r["actor"])).collect();
    assert_eq!(environments, (0..8).collect::<Vec<u64>>());
    for report in reports {
        assert!(
            u(&report["episodes"]) > 0,
            "an environment played no episode: {report}"
        );
        assert!(report["peak_rss_mb"].as_f64().unwrap() > 0.0, "{report}");
    }
    assert_cpu_times(&summary, true);
    assert_lossless(logs.path(), "batched");
    // One process (and one log) per four environments.
    let dir = logs.path().join("batched");
    for (process, exists) in [(0, true), (1, false), (4, true), (5, false)] {
        let log = dir.join(format!("actor-{process}-0.mcap"));
        assert_eq!(log.exists(), exists, "{}", log.display());
    }
}

/// Each role in its own process reports the CPU time it used over its working time, more
/// than none and no more than all the cores for that long; roles in threads of one process
/// report none.
fn assert_cpu_times(summary: &Value, own_processes: bool) {
    let cores = std::thread::available_parallelism().unwrap().get() as f64;
    let learner = &summary["learner"];
    let reports = summary["actors_reports"].as_array().unwrap();
    let timed = reports
        .iter()
        .filter(|r| u(&r["actions"]) > 0)
        .map(|r| (r, "acting_s"))
        .chain([(learner, "training_s")]);
    for (report, working) in timed {
        let cpu_s = report["cpu_s"].as_f64();
        if !own_processes {
            assert_eq!(cpu_s, None, "{report}");
            continue;
        }
        let cpu_s = cpu_s.unwrap_or_else(|| panic!("no CPU time in {report}"));
        let most = (report[working].as_f64().unwrap() + 0.1) * cores;
        assert!(cpu_s > 0.0 && cpu_s <= most, "{cpu_s} CPU s in {report}");
    }
}

/// The learner's time updating is some of its working time, not more; its steps, its
/// publications and its checkpoints are some of that.
fn assert_learner_busy(summary: &Value) {
    let learner = &summary["learner"];
    let seconds = |key: &str| learner[key].as_f64().unwrap();
    let (busy_s, training_s) = (seconds("busy_s"), seconds("training_s"));
    assert!(busy_s > 0.0 && busy_s <= training_s, "{learner}");
    let parts = ["step_s", "publish_s", "checkpoint_s"].map(seconds);
    assert!(
        parts[0] > 0.0 && parts.iter().all(|&s| s >= 0.0),
        "{learner}"
    );
    assert!(parts.iter().sum::<f64>() <= busy_s, "{learner}");
}

#[test]
fn the_buffer_snapshots_in_the_background_while_it_serves() {
    let logs = logs();
    let path = stage1::stage1_with(
        logs.path(),
        "snapshots",
        &[("buffer.snapshot_every_s", toml::Value::Float(0.25))],
    );
    succeeds(command_with(
        &path,
        logs.path(),
        &["--actors", "1", "--episodes", "20", "--run-id", "bg"],
    ));
    assert_lossless(logs.path(), "bg");
    let buffer = &summary(logs.path(), "bg")["buffer"];
    // The last one at the end, and others written while the run went on.
    assert!(u(&buffer["snapshots"]) >= 3, "{buffer}");
    assert!(buffer["snapshot_hold_ms_max"].as_f64().unwrap() > 0.0);
    assert!(logs.path().join("bg/buffer.snapshot.prev").exists());
}

#[test]
fn actors_share_the_buffer_when_the_learner_sets_the_pace() {
    // Grasp-only episodes are quicker than the learner's updates, so the buffer's rate
    // limiter holds the actors back: each must still get its steps in.
    let logs = logs();
    train_ok(
        logs.path(),
        &["--actors", "2", "--episodes", "80", "--run-id", "fair"],
    );
    let total = assert_lossless(logs.path(), "fair");
    let streams = summary(logs.path(), "fair")["buffer"]["streams"].clone();
    for actor in 0..2 {
        let steps: u64 = streams
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| u(&s["actor"]) == actor)
            .map(|s| u(&s["steps"]))
            .sum();
        assert!(
            steps * 5 >= total,
            "actor {actor} got {steps} of {total} steps in: {streams}"
        );
    }
}

/// `pushgrasp inspect <args>`: its output, or its error.
fn inspect_with(args: &[&std::ffi::OsStr]) -> Result<String, String> {
    let output = Command::new(env!("CARGO_BIN_EXE_pushgrasp"))
        .arg("inspect")
        .args(args)
        .output()
        .expect("pushgrasp runs");
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    if output.status.success() {
        Ok(stdout)
    } else {
        Err(stderr)
    }
}

/// `pushgrasp inspect --json` of a run directory.
fn inspect(dir: &Path) -> Value {
    let output = inspect_with(&[dir.as_os_str(), "--json".as_ref()]).unwrap();
    serde_json::from_str(&output).expect("one JSON object")
}

/// The Python `mcap` reader's message counts per topic of a file, if `make test` could
/// install it.
fn python_counts(file: &Path) -> Option<BTreeMap<String, u64>> {
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/mcap-venv/bin/python3");
    let script = "import sys, json, collections\n\
from mcap.reader import make_reader\n\
counts = collections.Counter()\n\
with open(sys.argv[1], 'rb') as f:\n\
    for schema, channel, message in make_reader(f).iter_messages():\n\
        counts[channel.topic] += 1\n\
print(json.dumps(counts))\n";
    let output = Command::new(&python)
        .args(["-c", script])
        .arg(file)
        .output()
        .ok()?;
    if !output.status.success() {
        eprintln!(
            "skipping the Python reader: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        return None;
    }
    Some(serde_json::from_slice(&output.stdout).expect("counts"))
}

/// `pushgrasp inspect`'s counts from a run's logs are the run summary's.
fn assert_logs_count_as_the_summary(report: &Value, summary: &Value) {
    let received = u(&summary["buffer"]["steps_received"]);
    assert_eq!(u(&report["steps_sent"]), received);
    assert_eq!(u(&report["steps_received"]), received);
    assert_eq!(report["episodes"], summary["buffer"]["episodes"]);
    assert_eq!(report["learner_updates"], summary["learner"]["updates"]);
}

#[test]
fn the_logs_of_a_run_say_what_the_processes_counted() {
    let logs = logs();
    train_ok(
        logs.path(),
        &["--actors", "2", "--episodes", "12", "--run-id", "logged"],
    );
    let dir = logs.path().join("logged");
    let summary = summary(logs.path(), "logged");
    let report = inspect(&dir);
    assert_logs_count_as_the_summary(&report, &summary);
    // The paper's metric by hand, from the buffer's curve.
    let curve = std::fs::read_to_string(dir.join("curve.csv")).unwrap();
    let grasped: Vec<bool> = curve
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1) == Some("1"))
        .collect();
    let last = &grasped[grasped.len().saturating_sub(30)..];
    let by_hand = last.iter().filter(|&&g| g).count() as f64 / last.len() as f64;
    let reported = report["goal_grasp_success_last30"].as_f64().unwrap();
    assert!(
        (reported - by_hand).abs() < 1e-12,
        "{reported} vs {by_hand}"
    );
    let files = report["files"].as_array().unwrap();
    assert_eq!(
        files.len(),
        5,
        "launcher, buffer, learner, 2 actors: {files:?}"
    );
    for file in files {
        assert_eq!(file["recovered"], false, "{file}");
        let ours: BTreeMap<String, u64> = file["channels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| (c[0].as_str().unwrap().to_string(), u(&c[1])))
            .collect();
        if let Some(theirs) = python_counts(Path::new(file["file"].as_str().unwrap())) {
            assert_eq!(ours, theirs, "{file}");
        }
        // Every process logs its memory, the binary's allocator counting its live bytes: a
        // role as it starts and as it ends, the launcher as it starts.
        let path = file["file"].as_str().unwrap();
        let memory = mcaplog::json_messages(path, PROCESS_MEMORY).unwrap();
        let least = if path.ends_with("launcher.mcap") {
            1
        } else {
            2
        };
        assert!(memory.len() >= least, "{path}: {memory:?}");
        for record in memory {
            let record: MemoryRecord = serde_json::from_value(record).unwrap();
            assert!(record.rss_mb > 0.0 && record.anon_mb > 0.0, "{record:?}");
            assert!(record.live_mb.is_some_and(|mb| mb > 0.0), "{record:?}");
        }
    }

    // A file cut mid-way is read as far as its complete chunks go, and recovered.
    let actor = dir.join("actor-0-0.mcap");
    let bytes = std::fs::read(&actor).unwrap();
    let cut = logs.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let damaged = inspect(&cut);
    assert_eq!(damaged["files"][0]["recovered"], true);
    let output = Command::new(env!("CARGO_BIN_EXE_pushgrasp"))
        .args(["logs", "recover"])
        .arg(&cut)
        .output()
        .unwrap();
    assert!(output.status.success());
    let repaired = inspect(&logs.path().join("cut.recovered.mcap"));
    assert_eq!(repaired["files"][0]["recovered"], false);
    assert_eq!(
        repaired["files"][0]["messages"],
        damaged["files"][0]["messages"]
    );
}

#[test]
fn a_run_logged_in_segments_reads_back_whole() {
    let logs = logs();
    // A segment every 0.3 s: a run of a few seconds writes several files per process.
    let args = [
        "--actors",
        "1",
        "--episodes",
        "8",
        "--run-id",
        "segmented",
        "--set",
        "logging.segment_minutes=0.005",
    ];
    train_ok(logs.path(), &args);
    let dir = logs.path().join("segmented");
    let summary = summary(logs.path(), "segmented");
    let report = inspect(&dir);
    assert_logs_count_as_the_summary(&report, &summary);
    let segments = mcaplog::segments(&dir.join("launcher.mcap"));
    assert!(segments.len() > 1, "{segments:?}");
    // The summary is logged as the run ends: in the last segment, found from the first file.
    let logged = mcaplog::newest_json_message(&segments[0], LAUNCHER_SUMMARY).unwrap();
    assert_eq!(logged.unwrap()["run_id"], "segmented");
    // Each segment is a whole file, each log's segments read in order after its first.
    let launcher: Vec<&str> = report["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|file| file["file"].as_str().unwrap())
        .filter(|file| file.contains("launcher"))
        .collect();
    let expected: Vec<String> = segments.iter().map(|s| s.display().to_string()).collect();
    assert_eq!(launcher, expected);
    for file in report["files"].as_array().unwrap() {
        assert_eq!(file["recovered"], false, "{file}");
    }
}

#[test]
fn inspect_draws_overlaid_curves_and_exports_an_episodes_pictures() {
    let logs = logs();
    for run in ["a", "b"] {
        train_ok(
            logs.path(),
            &[
                "--threads",
                "--actors",
                "2",
                "--episodes",
                "24",
                "--run-id",
                run,
            ],
        );
    }
    let (a, b) = (logs.path().join("a"), logs.path().join("b"));
    let both: Value = serde_json::from_str(
        &inspect_with(&[a.as_os_str(), b.as_os_str(), "--json".as_ref()]).unwrap(),
    )
    .unwrap();
    assert_eq!(both.as_array().map(Vec::len), Some(2));
    assert_eq!(both[1]["run"], "b");
    assert!(!both[0]["goal_grasp_q"].as_array().unwrap().is_empty());

    // One figure overlays both runs: SVG text names them, the PNG decodes.
    let svg = logs.path().join("curves.svg");
    let png = logs.path().join("curves.png");
    for figure in [&svg, &png] {
        inspect_with(&[
            a.as_os_str(),
            b.as_os_str(),
            "--plot".as_ref(),
            figure.as_os_str(),
        ])
        .unwrap();
    }
    let text = std::fs::read_to_string(&svg).unwrap();
    for label in ["Goal grasp success (last 30 episodes)", "Q*", "a", "b"] {
        assert!(text.lines().any(|l| l == label), "{label} not in the SVG");
    }
    let picture = image::open(&png).unwrap();
    assert!(picture.width() > 600 && picture.height() > 400);

    // Each actor logs the pictures of its first episode: the first episode taken in has them.
    let report = inspect(&a);
    let actor_file = &report["files"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["file"].as_str().unwrap().ends_with("actor-0-0.mcap"))
        .unwrap()["channels"];
    let on = |topic: &str| {
        actor_file
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c[0] == topic)
            .map_or(0, |c| u(&c[1]))
    };
    assert!(on("/actor/scene") >= 1 && on("/actor/scene") == on("/actor/colour"));
    let out = logs.path().join("episode-1");
    let said = inspect_with(&[
        a.as_os_str(),
        "--episode".as_ref(),
        "1".as_ref(),
        "--export".as_ref(),
        out.as_os_str(),
    ])
    .unwrap();
    assert!(said.contains("files written"), "{said}");
    let colour = image::open(out.join("step-0-colour.png"))
        .unwrap()
        .to_rgb8();
    assert_eq!(colour.dimensions(), (112, 112));
    assert!(
        colour.pixels().any(|p| p != colour.get_pixel(0, 0)),
        "a flat picture"
    );
    let height = image::open(out.join("step-0-height.png")).unwrap();
    assert_eq!(height.color(), image::ColorType::L16);
    let episode = json(&out.join("episode.json"));
    assert_eq!(episode["episode"]["number"], 1);
    assert_eq!(episode["steps"].as_array().unwrap().len(), 1);

    // An episode without pictures, and one beyond the run, are refused with the reason.
    // Which episodes have pictures depends on how the actors interleave: the table says.
    let table = inspect_with(&[a.as_os_str(), "--episodes".as_ref()]).unwrap();
    let without = table
        .lines()
        .skip_while(|l| !l.starts_with("episode "))
        .skip(1)
        .find(|row| !row.ends_with("yes"))
        .and_then(|row| row.split_whitespace().next())
        .unwrap_or_else(|| panic!("no episode without pictures in\n{table}"))
        .to_string();
    let err = inspect_with(&[
        a.as_os_str(),
        "--episode".as_ref(),
        without.as_ref(),
        "--export".as_ref(),
        out.as_os_str(),
    ])
    .unwrap_err();
    assert!(
        err.contains("has no pictures") && err.contains("episodes with pictures: 1"),
        "{err}"
    );
    let err = inspect_with(&[
        a.as_os_str(),
        "--episode".as_ref(),
        "100000".as_ref(),
        "--export".as_ref(),
        out.as_os_str(),
    ])
    .unwrap_err();
    assert!(err.contains("no episode 100000"), "{err}");
}

#[test]
fn two_actor_threads_over_channels_lose_no_step() {
    let logs = logs();
    train_ok(
        logs.path(),
        &[
            "--threads",
            "--actors",
            "2",
            "--episodes",
            "16",
            "--run-id",
            "threads",
        ],
    );
    assert!(assert_lossless(logs.path(), "threads") >= 16);
    let summary = summary(logs.path(), "threads");
    assert_cpu_times(&summary, false);
    assert_learner_busy(&summary);
}

#[test]
fn trial_grasps_reach_the_buffer_as_experience_not_as_episodes() {
    let logs = logs();
    let config = logs.path().join("trials.toml");
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(CONFIG)).unwrap();
    std::fs::write(&config, format!("grasp_trials = 3\n{text}")).unwrap();
    succeeds(command_with(
        &config,
        logs.path(),
        &["--threads", "--episodes", "12", "--run-id", "trials"],
    ));
    let received = assert_lossless(logs.path(), "trials");
    let summary = summary(logs.path(), "trials");
    let buffer = &summary["buffer"];
    let mut trials = 0;
    for report in summary["actors_reports"].as_array().unwrap() {
        // Stage 1 grasps at every action, and three trials go before each.
        assert_eq!(u(&report["trials"]), 3 * u(&report["actions"]), "{report}");
        trials += u(&report["trials"]);
    }
    assert!(trials >= 36, "{trials} trials for at least 12 grasps");
    assert_eq!(u(&buffer["trials"]), trials);
    let episodes = u(&buffer["episodes"]);
    assert!((12..trials).contains(&episodes), "{episodes} episodes");
    // Every trial and every grasp but the last few waiting for their next state arrived.
    assert!(received >= trials + episodes, "{received} steps");
    // The logs count the trials as steps, and only the executed grasps as episodes.
    let report = inspect(&logs.path().join("trials"));
    assert_eq!(u(&report["steps_received"]), received);
    assert_eq!(u(&report["episodes"]), episodes);
}

#[test]
fn a_killed_actor_is_restarted_and_the_run_finishes() {
    let logs = logs();
    // A budget it will not reach: the run is stopped once the new actor has worked a while.
    let mut run = command(
        logs.path(),
        &["--actors", "2", "--episodes", "100000", "--run-id", "kill"],
    )
    .stdout(Stdio::null())
    .stderr(Stdio::piped())
    .spawn()
    .expect("pushgrasp starts");
    let entries = wait_for_processes(logs.path(), "kill", 4);
    // Let it act and send a few steps first.
    std::thread::sleep(Duration::from_secs(3));
    signal(pid_of(&entries, "actor-0-0"), "KILL");
    let deadline = Instant::now() + Duration::from_secs(60);
    while !wait_for_processes(logs.path(), "kill", 4)
        .iter()
        .any(|e| e["role"] == "actor-0-1")
    {
        assert!(
            Instant::now() < deadline,
            "the killed actor was not restarted"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    std::thread::sleep(Duration::from_secs(3));
    signal(run.id() as i32, "INT");
    let status = wait_exit(&mut run, Duration::from_secs(300));
    assert!(status.success(), "the run failed after the kill: {status}");
    let summary = summary(logs.path(), "kill");
    assert!(u(&summary["restarts"]) >= 1);
    let faults = summary["faults"].as_array().unwrap();
    assert!(
        faults.iter().any(|f| f["role"] == "actor-0-0"
            && f["restarted"] == true
            && f["lost_messages"].is_u64()),
        "the killed actor is not among the faults: {faults:?}"
    );
    assert!(summary["failure"].is_null());
    let reports = summary["actors_reports"].as_array().unwrap();
    assert!(
        reports
            .iter()
            .any(|r| r["actor"] == 0 && u(&r["incarnation"]) >= 1),
        "no report of actor 0's second incarnation: {reports:?}"
    );
    assert_lossless(logs.path(), "kill");
}

/// The weight versions the launcher saw the learner publish, in order.
fn published_versions(logs: &Path, run: &str) -> Vec<u64> {
    mcaplog::json_messages(logs.join(run).join("launcher.mcap"), "/launcher/progress")
        .expect("the launcher's log")
        .iter()
        .map(|progress| u(&progress["weights_version"]))
        .collect()
}

/// Starts a 1-actor run of 300 episodes from `config`, lets it train 2 s, sends `role`
/// `kill`; returns whether the run succeeded once it ended, and the role's pid.
fn role_fault(config: &Path, logs: &Path, run: &str, role: &str, kill: &str) -> (bool, i32) {
    fault_once(config, logs, run, 1, role, kill, || {
        std::thread::sleep(Duration::from_secs(2))
    })
}

/// Starts a run of `actors` actor processes and 300 episodes from `config`, sends `role`
/// `kill` once its roles are up and `ready` returns; returns whether the run succeeded once
/// it ended, and the role's pid.
fn fault_once(
    config: &Path,
    logs: &Path,
    run: &str,
    actors: usize,
    role: &str,
    kill: &str,
    ready: impl FnOnce(),
) -> (bool, i32) {
    let mut child = command_with(
        config,
        logs,
        &[
            "--actors",
            &actors.to_string(),
            "--episodes",
            "300",
            "--run-id",
            run,
        ],
    )
    .stdout(Stdio::null())
    .stderr(Stdio::piped())
    .spawn()
    .expect("pushgrasp starts");
    let pid = pid_of(&wait_for_processes(logs, run, 2 + actors), role);
    ready();
    signal(pid, kill);
    let status = wait_exit(&mut child, Duration::from_secs(300));
    (status.success(), pid)
}

/// The tests that judge roles by a 3 s heartbeat and the 64-actor run, which takes every
/// core, run one at a time: beside that run, a role just started can be silent for 3 s.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// The stage-1 config with a 3 s heartbeat timeout and a buffer snapshot every second,
/// written into `logs`, and the turn of a test that uses it ([`one_at_a_time`]).
fn impatient_config(logs: &Path) -> (std::path::PathBuf, MutexGuard<'static, ()>) {
    impatient_config_with(logs, &[])
}

/// [`impatient_config`] with more settings.
fn impatient_config_with(
    logs: &Path,
    more: &[(&str, toml::Value)],
) -> (std::path::PathBuf, MutexGuard<'static, ()>) {
    let turn = one_at_a_time();
    let mut settings = vec![
        ("run.heartbeat_timeout_s", toml::Value::Float(3.0)),
        ("buffer.snapshot_every_s", toml::Value::Float(1.0)),
    ];
    settings.extend(more.iter().cloned());
    let config = stage1::stage1_with(logs, "impatient", &settings);
    (config, turn)
}

/// What a run whose learner was restarted must show: the run reached its budget, the fault
/// was recorded as restarted, the restarted learner reported, and the versions never fell.
fn assert_learner_restarted(logs: &Path, run: &str, cause: &str) {
    let summary = summary(logs, run);
    assert!(summary["failure"].is_null(), "{}", summary["failure"]);
    let faults = summary["faults"].as_array().unwrap();
    assert!(
        faults.iter().any(|f| f["role"] == "learner"
            && f["restarted"] == true
            && f["cause"].as_str().unwrap_or_default().contains(cause)),
        "{faults:?}"
    );
    assert!(u(&summary["buffer"]["episodes"]) >= 300);
    assert!(logs.join(run).join("reports/learner-1.json").exists());
    let versions = published_versions(logs, run);
    assert!(
        versions.windows(2).all(|w| w[0] <= w[1]),
        "a weight version went back: {versions:?}"
    );
    assert_lossless(logs, run);
}

#[test]
fn a_killed_learner_is_restarted_and_its_weight_versions_keep_rising() {
    let logs = logs();
    let (ok, _) = role_fault(
        Path::new(CONFIG),
        logs.path(),
        "learner-dies",
        "learner",
        "KILL",
    );
    assert!(ok, "the run failed after the learner was killed");
    assert_learner_restarted(logs.path(), "learner-dies", "signal: 9");
}

#[test]
fn a_hung_learner_is_noticed_killed_and_restarted() {
    let logs = logs();
    let (config, _turn) = impatient_config(logs.path());
    let (ok, learner) = role_fault(&config, logs.path(), "hung", "learner", "STOP");
    assert!(ok, "the run failed after the learner hung");
    assert_learner_restarted(logs.path(), "hung", "no status report");
    assert!(
        !Path::new(&format!("/proc/{learner}")).exists(),
        "the hung learner is still there"
    );
}

/// Two actors beside a learner that sets the pace (8 samples per insert), so the buffer's
/// rate limiter holds them back most of the time: the one stopped is noticed by its own
/// silence, the other, waiting in its sends, is not taken for hung.
#[test]
fn a_hung_actor_beside_a_held_one_is_killed_and_restarted() {
    let logs = logs();
    let (config, _turn) = impatient_config_with(
        logs.path(),
        &[("buffer.samples_per_insert", toml::Value::Float(8.0))],
    );
    let (ok, actor) = fault_once(
        &config,
        logs.path(),
        "actor-hangs",
        2,
        "actor-0-0",
        "STOP",
        || std::thread::sleep(Duration::from_secs(2)),
    );
    assert!(ok, "the run failed after an actor hung");
    let actor_summary = summary(logs.path(), "actor-hangs");
    let faults = actor_summary["faults"].as_array().unwrap();
    assert!(
        faults.len() == 1
            && faults[0]["role"] == "actor-0-0"
            && faults[0]["restarted"] == true
            && faults[0]["lost_messages"].is_u64()
            && faults[0]["cause"]
                .as_str()
                .unwrap_or_default()
                .contains("no status report"),
        "one fault, the hung actor's: {faults:?}"
    );
    assert_eq!(u(&actor_summary["restarts"]), 1);
    assert!(u(&actor_summary["buffer"]["episodes"]) >= 300);
    assert!(!Path::new(&format!("/proc/{actor}")).exists());
}

/// [`fault_once`] on the buffer once a snapshot holds 20 episodes.
fn buffer_fault(config: &Path, logs: &Path, run: &str, kill: &str) -> (bool, i32) {
    let counters = logs.join(run).join("buffer-counters.json");
    fault_once(config, logs, run, 1, "buffer", kill, || {
        let deadline = Instant::now() + Duration::from_secs(120);
        while std::fs::read(&counters)
            .ok()
            .and_then(|bytes| serde_json::from_slice::<Value>(&bytes).ok())
            .is_none_or(|saved| saved["report"]["episodes"].as_u64() < Some(20))
        {
            assert!(Instant::now() < deadline, "no snapshot of 20 episodes");
            std::thread::sleep(Duration::from_millis(100));
        }
    })
}

/// What a run whose buffer was restarted must show: the run reached its budget with no
/// actor restarted; the fault was recorded as restarted, with what the restart lost; the
/// restarted buffer took over the snapshot's replay and reported; every step an actor sent
/// arrived or was counted lost to the restart, and nothing else is missing.
fn assert_buffer_restarted(logs: &Path, run: &str, cause: &str) {
    let summary = summary(logs, run);
    assert!(summary["failure"].is_null(), "{}", summary["failure"]);
    assert_eq!(
        u(&summary["restarts"]),
        1,
        "not the buffer alone was restarted"
    );
    let buffer = &summary["buffer"];
    assert!(u(&buffer["episodes"]) >= 300);
    let faults = summary["faults"].as_array().unwrap();
    let fault = faults
        .iter()
        .find(|f| f["role"] == "buffer")
        .unwrap_or_else(|| panic!("no buffer fault in {faults:?}"));
    assert!(
        fault["restarted"] == true && fault["cause"].as_str().unwrap().contains(cause),
        "{fault}"
    );
    let streams = buffer["streams"].as_array().unwrap();
    let lost: u64 = streams.iter().map(|s| u(&s["lost_in_restart"])).sum();
    assert_eq!(u(&buffer["lost_in_restarts"]), lost);
    assert_eq!(u(&fault["lost_messages"]), lost, "{fault}");
    for stream in streams {
        assert_eq!(u(&stream["missing"]), 0, "a gap in {stream}");
    }
    for report in summary["actors_reports"].as_array().unwrap() {
        let stream = streams
            .iter()
            .find(|s| s["actor"] == report["actor"] && s["incarnation"] == report["incarnation"])
            .unwrap_or_else(|| panic!("no stream for {report}"));
        assert!(
            u(&stream["steps"]) + u(&stream["lost_in_restart"]) >= u(&report["steps_sent"]),
            "steps neither received nor counted lost: {stream} {report}"
        );
    }
    let dir = logs.join(run);
    assert!(dir.join("reports/buffer-1.json").exists());
    let log = std::fs::read_to_string(dir.join("buffer-1.log")).unwrap();
    let restored: u64 = log
        .split("restored ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("buffer-1.log says nothing restored:\n{log}"));
    assert!(restored >= 20, "restored {restored} items");
}

#[test]
fn a_killed_or_hung_buffer_is_restarted_from_its_snapshot_with_the_loss_counted() {
    let logs = logs();
    let (config, _turn) = impatient_config(logs.path());
    let (ok, _) = buffer_fault(&config, logs.path(), "buffer-dies", "KILL");
    assert!(ok, "the run failed after the buffer was killed");
    assert_buffer_restarted(logs.path(), "buffer-dies", "signal: 9");

    // Hung: the actor and the learner, waiting on it, fall silent too; only the buffer is
    // killed.
    let (ok, buffer) = buffer_fault(&config, logs.path(), "buffer-hangs", "STOP");
    assert!(ok, "the run failed after the buffer hung");
    assert_buffer_restarted(logs.path(), "buffer-hangs", "no status report");
    assert!(!Path::new(&format!("/proc/{buffer}")).exists());
}

#[test]
fn a_damaged_newest_snapshot_and_checkpoint_resume_from_the_previous_generation() {
    let logs = logs();
    let run = |episodes: &str, resume: bool| {
        let mut args = vec!["--actors", "1", "--episodes", episodes, "--run-id", "gens"];
        if resume {
            args.push("--resume");
        }
        train_ok(logs.path(), &args);
    };
    // Two generations: the first run's state, then the resumed run's.
    run("30", false);
    run("60", true);
    let dir = logs.path().join("gens");
    assert!(dir.join("buffer.snapshot.prev").exists() && dir.join("checkpoint.prev").exists());
    std::fs::write(dir.join("buffer.snapshot"), b"not a snapshot").unwrap();
    std::fs::write(dir.join("checkpoint/manifest.toml"), b"[[[").unwrap();
    let third = command(
        logs.path(),
        &[
            "--actors",
            "1",
            "--episodes",
            "90",
            "--run-id",
            "gens",
            "--resume",
        ],
    )
    .output()
    .unwrap();
    assert!(third.status.success());
    // On the console, where the person running it looks, and in each role's log.
    let console = String::from_utf8_lossy(&third.stderr);
    for (role, damaged) in [("buffer", "buffer.snapshot"), ("learner", "checkpoint")] {
        assert!(
            console.contains(&format!("warning from the {role}: "))
                && console.contains(&format!("{damaged} is damaged")),
            "the console:\n{console}"
        );
        let log = std::fs::read_to_string(dir.join(format!("{role}.log"))).unwrap();
        assert!(
            log.contains(&format!("{damaged} is damaged")) && log.contains(".prev"),
            "{role}.log:\n{log}"
        );
    }
    assert!(u(&summary(logs.path(), "gens")["buffer"]["episodes"]) >= 90);
}

#[test]
fn a_snapshot_on_request_then_ctrl_c_leaves_a_checkpoint_a_snapshot_and_reports_and_resume_continues()
 {
    let logs = logs();
    let mut run = command(
        logs.path(),
        &["--actors", "1", "--episodes", "100000", "--run-id", "int"],
    )
    .stdout(Stdio::null())
    .stderr(Stdio::piped())
    .spawn()
    .expect("pushgrasp starts");
    wait_for_processes(logs.path(), "int", 3);
    std::thread::sleep(Duration::from_secs(4));
    // A snapshot on request, while the run goes on.
    let snapshot = logs.path().join("int/buffer.snapshot");
    signal(run.id() as i32, "USR1");
    let deadline = Instant::now() + Duration::from_secs(60);
    while !snapshot.exists() {
        assert!(Instant::now() < deadline, "SIGUSR1 gave no snapshot");
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(
        run.try_wait().unwrap().is_none(),
        "the run stopped at a snapshot"
    );
    std::thread::sleep(Duration::from_secs(2));
    signal(run.id() as i32, "INT");
    let status = wait_exit(&mut run, Duration::from_secs(180));
    assert!(status.success(), "an interrupted run failed: {status}");
    let first = summary(logs.path(), "int");
    assert_eq!(first["interrupted"], true);
    let steps = assert_lossless(logs.path(), "int");
    let (episodes, updates) = (
        u(&first["buffer"]["episodes"]),
        u(&first["learner"]["updates"]),
    );

    let more = (episodes + 6).to_string();
    train_ok(
        logs.path(),
        &["--resume", "--run-id", "int", "--episodes", &more],
    );
    let second = summary(logs.path(), "int");
    assert_eq!(second["interrupted"], false);
    assert!(u(&second["buffer"]["episodes"]) >= episodes + 6);
    assert!(u(&second["buffer"]["steps_received"]) > steps);
    assert!(
        u(&second["learner"]["updates"]) > updates,
        "the learner restarted its count instead of continuing"
    );
    assert_eq!(
        u(&second["learner"]["session_updates"]),
        u(&second["learner"]["updates"]) - updates,
        "the resumed learner's own updates are the run's beyond the checkpoint's"
    );
    assert_lossless(logs.path(), "int");
}

#[test]
fn a_role_that_fails_the_same_way_as_it_starts_is_not_started_again() {
    let logs = logs();
    // Nets to start from that are not there: the learner fails as it starts, every time.
    let nothing = tempfile::tempdir().unwrap();
    let output = command(
        logs.path(),
        &[
            "--actors",
            "1",
            "--episodes",
            "50",
            "--run-id",
            "loop",
            "--init-from",
        ],
    )
    .arg(nothing.path())
    .output()
    .unwrap();
    assert!(!output.status.success());
    let console = String::from_utf8_lossy(&output.stderr);
    assert!(
        console.contains("the learner-1 failed twice the same way as it started")
            && console.contains("manifest"),
        "{console}"
    );
    let dir = logs.path().join("loop");
    assert!(dir.join("learner-1.log").exists() && !dir.join("learner-2.log").exists());
    let summary = summary(logs.path(), "loop");
    assert_eq!(u(&summary["restarts"]), 1, "{summary}");
    let faults = summary["faults"].as_array().unwrap();
    assert_eq!(faults.len(), 2, "{faults:?}");
    assert!(faults[1]["restarted"] == false && faults[0]["cause"] == faults[1]["cause"]);
}

#[test]
fn runs_at_once_stay_apart_even_with_one_id_in_two_log_directories() {
    let logs = logs();
    let other = logs.path().join("other");
    // (log directory, run id, actors): a pipeline's stages are all `stage<N>`, each in its
    // pipeline's directory.
    let runs = [
        (logs.path(), "a", 1),
        (logs.path(), "b", 2),
        (other.as_path(), "a", 2),
    ];
    let mut children: Vec<Child> = runs
        .iter()
        .map(|&(dir, run, actors)| {
            command(
                dir,
                &[
                    "--actors",
                    &actors.to_string(),
                    "--episodes",
                    "10",
                    "--run-id",
                    run,
                ],
            )
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("pushgrasp starts")
        })
        .collect();
    for child in &mut children {
        assert!(wait_exit(child, Duration::from_secs(300)).success());
    }
    for (dir, run, actors) in runs {
        assert_lossless(dir, run);
        let streams = summary(dir, run)["buffer"]["streams"].clone();
        let seen: std::collections::BTreeSet<u64> = streams
            .as_array()
            .unwrap()
            .iter()
            .map(|s| u(&s["actor"]))
            .collect();
        // Only its own actors: a run of one actor that heard actor 1 heard another run.
        assert!(
            seen.iter().all(|&actor| actor < actors),
            "run {run} heard {streams}"
        );
    }
}

#[test]
fn a_bad_config_is_refused_naming_the_file_and_field_before_anything_starts() {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(CONFIG)).unwrap();
    // The buffer's rate limit used to be checked only once its role had started.
    for (from, to, field) in [
        ("stage = 1", "stage = 4", "stage"),
        ("gamma = 0.5", "gamma = 1.5", "learning.gamma"),
        (
            "samples_per_insert = 4.0",
            "samples_per_insert = 0.0",
            "buffer.samples_per_insert",
        ),
    ] {
        let logs = logs();
        let bad = logs.path().join("bad.toml");
        assert!(text.contains(from), "{CONFIG} has no `{from}`");
        std::fs::write(&bad, text.replace(from, to)).unwrap();
        let output = Command::new(env!("CARGO_BIN_EXE_pushgrasp"))
            .args(["train", "--config"])
            .arg(&bad)
            .arg("--logs")
            .arg(logs.path())
            .output()
            .unwrap();
        assert!(!output.status.success());
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(stderr.contains(&format!("bad.toml: {field}: ")), "{stderr}");
        let left: Vec<_> = std::fs::read_dir(logs.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .filter(|name| name != "bad.toml")
            .collect();
        assert!(left.is_empty(), "a refused run left {left:?}");
    }
}
