//! The launcher's own faults. A run killed at any moment of its start-up (or just after it
//! finished), every process of it at once, continues with `--resume`: the shared memory its
//! processes were creating is cleaned up, its logs go on after the killed launch's, and a
//! resumed run whose budget is already spent stops at once. A hung launcher's roles stop by
//! themselves, saving their state.

use std::collections::BTreeMap;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

#[path = "common/stage1.rs"]
mod stage1;

const RUN: &str = "k";

/// `train` of a 1-actor stage-1 run of 20 episodes.
fn train(logs: &Path, extra: &[&str]) -> Command {
    let mut command = train_with(Path::new("configs/stage1.toml"), logs, extra);
    command.args(["--episodes", "20"]);
    command
}

fn train_with(config: &Path, logs: &Path, extra: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_pushgrasp"));
    command
        .args(["train", "--run-id", RUN, "--actors", "1"])
        .arg("--config")
        .arg(config)
        .arg("--logs")
        .arg(logs)
        .args(extra)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    command
}

/// How many roles the run's processes file lists.
fn roles_listed(run: &Path) -> usize {
    std::fs::read(run.join("processes.json"))
        .ok()
        .and_then(|bytes| serde_json::from_slice::<Value>(&bytes).ok())
        .and_then(|entries| entries.as_array().map(Vec::len))
        .unwrap_or(0)
}

/// The run directory's MCAP files, with what each holds.
fn mcap_files(run: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let Ok(entries) = std::fs::read_dir(run) else {
        return BTreeMap::new();
    };
    entries
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "mcap"))
        .map(|path| {
            let bytes = std::fs::read(&path).unwrap();
            (path, bytes)
        })
        .collect()
}

/// What an ended run wrote to its stderr.
fn stderr_of(child: &mut Child) -> String {
    let mut stderr = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut stderr).unwrap();
    stderr
}

fn wait(child: &mut Child, timeout: Duration, what: &str) -> ExitStatus {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        if Instant::now() > deadline {
            let _ = Command::new("kill")
                .args(["-9", "--", &format!("-{}", child.id())])
                .status();
            panic!("{what} did not end within {timeout:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Starts a run in a process group of its own, kills the whole group with SIGKILL once
/// `moment` holds of its run directory, then resumes it: the resumed run must complete.
fn killed_then_resumed(what: &str, moment: impl Fn(&Path) -> bool) {
    let logs = tempfile::tempdir().unwrap();
    let run = logs.path().join(RUN);
    let mut first = train(logs.path(), &[]).process_group(0).spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    while !moment(&run) {
        if first.try_wait().unwrap().is_some() && !moment(&run) {
            let stderr = stderr_of(&mut first);
            panic!("{what}: the run ended before the moment: {stderr}");
        }
        assert!(Instant::now() < deadline, "{what}: the moment never came");
        std::thread::sleep(Duration::from_millis(1));
    }
    // (A run that has just finished may be gone already.)
    let _ = Command::new("kill")
        .args(["-9", "--", &format!("-{}", first.id())])
        .stderr(Stdio::null())
        .status();
    wait(&mut first, Duration::from_secs(10), "the killed run");
    // Its roles, killed with it, are gone before the resume looks for them.
    std::thread::sleep(Duration::from_millis(200));
    let logs_before = mcap_files(&run);

    let mut resumed = train(logs.path(), &["--resume"])
        .process_group(0)
        .spawn()
        .unwrap();
    // Well within the 120 s a role is given to stop before it is killed.
    let status = wait(&mut resumed, Duration::from_secs(90), "the resumed run");
    let stderr = stderr_of(&mut resumed);
    assert!(status.success(), "{what}: --resume failed: {stderr}");
    assert!(
        !stderr.contains("did not stop"),
        "{what}: a role missed its order to stop: {stderr}"
    );
    // The resumed processes went on after the killed ones' logs, which are as they were.
    let logs_after = mcap_files(&run);
    for (path, bytes) in &logs_before {
        assert!(
            logs_after.get(path) == Some(bytes),
            "{what}: the resume changed or removed {}",
            path.display()
        );
    }
    if logs_before.contains_key(&run.join("launcher.mcap")) {
        assert!(
            logs_after.contains_key(&run.join("launcher.1.mcap")),
            "{what}: the resumed launcher's log is not the next segment: {:?}",
            logs_after.keys()
        );
    }
    let summary: Value =
        serde_json::from_slice(&std::fs::read(run.join("summary.json")).unwrap()).unwrap();
    assert!(
        summary["buffer"]["episodes"].as_u64().unwrap() >= 20,
        "{what}: {}",
        summary["buffer"]
    );
}

#[test]
fn a_run_killed_while_it_starts_or_just_after_it_ends_resumes() {
    killed_then_resumed("killed once its config was written", |run| {
        run.join("config.toml").exists()
    });
    killed_then_resumed("killed while the buffer starts", |run| {
        roles_listed(run) >= 1
    });
    killed_then_resumed("killed while the learner starts", |run| {
        roles_listed(run) >= 2
    });
    killed_then_resumed("killed while the actor starts", |run| {
        roles_listed(run) >= 3
    });
    killed_then_resumed("killed once it finished", |run| {
        run.join("summary.json").exists()
    });
}

/// The pids of the roles the run's processes file lists.
fn role_pids(run: &Path) -> Vec<u64> {
    std::fs::read(run.join("processes.json"))
        .ok()
        .and_then(|bytes| serde_json::from_slice::<Value>(&bytes).ok())
        .and_then(|entries| {
            entries
                .as_array()
                .map(|e| e.iter().filter_map(|e| e["pid"].as_u64()).collect())
        })
        .unwrap_or_default()
}

/// Whether process `pid` runs (a zombie has ended).
fn alive(pid: u64) -> bool {
    std::fs::read(format!("/proc/{pid}/cmdline")).is_ok_and(|cmdline| !cmdline.is_empty())
}

#[test]
fn the_roles_of_a_hung_launcher_stop_by_themselves_and_the_run_resumes() {
    let logs = tempfile::tempdir().unwrap();
    let run = logs.path().join(RUN);
    let impatient = stage1::stage1_with(
        logs.path(),
        "impatient",
        &[("run.heartbeat_timeout_s", toml::Value::Float(3.0))],
    );
    let mut launcher = train_with(&impatient, logs.path(), &["--episodes", "100000"])
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    while roles_listed(&run) < 3 {
        if launcher.try_wait().unwrap().is_some() {
            let stderr = stderr_of(&mut launcher);
            panic!("the launcher ended before its roles started: {stderr}");
        }
        if Instant::now() > deadline {
            let _ = launcher.kill();
            panic!("the roles never started");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_secs(2));
    let roles = role_pids(&run);
    let stop = |signal: &str| {
        Command::new("kill")
            .args([signal, &launcher.id().to_string()])
            .status()
            .unwrap()
    };
    assert!(stop("-STOP").success());
    // Its heartbeat goes stale after 3 s; every role looks once a second, then saves.
    let deadline = Instant::now() + Duration::from_secs(60);
    while roles.iter().any(|&pid| alive(pid)) {
        assert!(
            Instant::now() < deadline,
            "roles of a hung launcher still run after 60 s"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    for role in ["buffer", "learner", "actor-0-0"] {
        let log = std::fs::read_to_string(run.join(format!("{role}.log"))).unwrap();
        assert!(
            log.contains("launcher has not beaten"),
            "{role}.log:\n{log}"
        );
        assert!(run.join(format!("reports/{role}.json")).exists(), "{role}");
    }
    stop("-KILL");
    launcher.wait().unwrap();

    let mut resumed = train_with(&impatient, logs.path(), &["--resume", "--episodes", "40"])
        .spawn()
        .unwrap();
    let status = wait(&mut resumed, Duration::from_secs(120), "the resumed run");
    assert!(status.success());
}
