//! `pushgrasp bench e2e`: the whole system's throughput. Real `train` runs (processes over
//! shared memory) with 1, 2 and 4 actors; actions per second summed over the actors (each
//! actor's actions over its own acting time, so process start-up is left out) and the
//! learner's updates per second, read from the runs' reports; and what an action and an
//! update cost in CPU time (each role's process over the same time), which leaves out the
//! time a role waits: on the rate limiter, or for a core the other roles hold.

use std::path::Path;
use std::process::Command;

use anyhow::{Context, Result, bail};
use clap::Args;
use serde_json::{Map, Value};

use super::print_figures;
use runtime::{RunDir, read_json};

#[derive(Args)]
pub struct E2eBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// The run config.
    #[arg(long, default_value = "configs/stage1.toml")]
    config: String,
    /// Episodes per run, at least two per environment.
    #[arg(long, default_value_t = 40)]
    episodes: u64,
    /// The runs' environment counts, one run each: actor processes of one environment each
    /// (`--environments 1,2,4,64,128`).
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 2, 4])]
    environments: Vec<u32>,
}

pub fn bench_e2e(args: &E2eBenchArgs) -> Result<()> {
    let logs = tempfile::tempdir()?;
    let mut figures = Map::new();
    figures.insert("episodes_per_run".into(), args.episodes.into());
    for &actors in &args.environments {
        let summary = train_run(
            Path::new(&args.config),
            actors,
            args.episodes.max(2 * u64::from(actors)),
            logs.path(),
            &format!("bench-e2e-{actors}"),
        )?;
        let learner = &summary["learner"];
        let updates_per_s = learner["session_updates"].as_f64().unwrap_or(0.0)
            / learner["training_s"].as_f64().unwrap_or(1.0).max(1e-9);
        figures.insert(
            format!("actions_per_s_{actors}"),
            round(actions_per_s(&summary)),
        );
        figures.insert(
            format!("learner_updates_per_s_{actors}"),
            round(updates_per_s),
        );
        let updates = learner["session_updates"].as_f64().unwrap_or(0.0);
        let (actor_cpu_s, actions) = actors_cpu_s_and_actions(&summary);
        let learner_cpu_s = learner["cpu_s"].as_f64().unwrap_or(0.0);
        figures.insert(
            format!("actor_cpu_ms_per_action_{actors}"),
            round(1e3 * actor_cpu_s / actions.max(1.0)),
        );
        figures.insert(
            format!("learner_cpu_ms_per_update_{actors}"),
            round(1e3 * learner_cpu_s / updates.max(1.0)),
        );
    }
    print_figures(&Value::Object(figures), args.json)
}

/// Runs `pushgrasp train` (processes over shared memory) into `logs/<name>-<pid>` and returns
/// its summary.
pub(super) fn train_run(
    config: &Path,
    actors: u32,
    episodes: u64,
    logs: &Path,
    name: &str,
) -> Result<Value> {
    let run_id = format!("{name}-{}", std::process::id());
    let output = Command::new(std::env::current_exe()?)
        .arg("train")
        .arg("--config")
        .arg(config)
        .args(["--actors", &actors.to_string()])
        .args(["--episodes", &episodes.to_string()])
        .args(["--run-id", &run_id])
        .arg("--logs")
        .arg(logs)
        .output()
        .context("running train")?;
    if !output.status.success() {
        bail!(
            "train with {actors} actors failed:\n{}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
    read_json(&RunDir::in_logs(logs, &run_id).summary())
}

/// Actions per second summed over a run's actors, each over its own acting time (process
/// start-up left out).
pub(super) fn actions_per_s(summary: &Value) -> f64 {
    summary["actors_reports"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|r| r["actions"].as_f64().unwrap_or(0.0) / r["acting_s"].as_f64().unwrap_or(1.0))
        .sum()
}

/// The CPU seconds of a run's actors over their acting time, and their actions, summed.
fn actors_cpu_s_and_actions(summary: &Value) -> (f64, f64) {
    let reports = summary["actors_reports"]
        .as_array()
        .map_or(&[][..], Vec::as_slice);
    let sum = |key: &str| -> f64 { reports.iter().map(|r| r[key].as_f64().unwrap_or(0.0)).sum() };
    (sum("cpu_s"), sum("actions"))
}

pub(super) fn round(x: f64) -> Value {
    ((x * 100.0).round() / 100.0).into()
}
