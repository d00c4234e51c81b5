//! `pushgrasp bench e2e`: the whole system's throughput. Real `train` runs (processes over
//! shared memory) with 1, 2 and 4 environments, each in an actor process of its own or K to
//! a process (`--envs-per-actor`), and with each learner backend asked for (`--learners`);
//! actions per second summed over the environments (each one's actions over its own acting
//! time, so process start-up is left out) and the learner's updates per second, the share
//! of its time it spent updating (the rest it waited on the actors), its updates per
//! second of that time and an update's share of it by part (the step, the publication, the
//! checkpoints, the rest), read from the runs' reports; what an action and an update cost in
//! CPU time (each role's process over the same time), which leaves out the time a role
//! waits: on the rate limiter, or for a core the other roles hold; and the actors' peak
//! resident memory per environment.

use std::path::Path;
use std::process::Command;

use anyhow::{Context, Result, bail};
use clap::Args;
use serde_json::{Map, Value};

use super::print_figures;
use rundir::LearnerReport;
use rundir::backend::Backend;
use rundir::{RunDir, read_json};

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
    /// The runs' environment counts (`--environments 1,2,4,64,128`).
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 2, 4])]
    environments: Vec<u32>,
    /// Environments per actor process (`--envs-per-actor 1,2,4,8`): one run for each count
    /// of environments it divides. A figure's name ends in the environments, then `_k` and
    /// this count where it is above 1.
    #[arg(long, value_delimiter = ',', default_values_t = [1u32])]
    envs_per_actor: Vec<u32>,
    /// The learner's backends (`--learners cpu,wgpu`, wgpu in a wgpu build): each run once
    /// with each, the actors on the CPU; without, the config's learner. A wgpu learner's
    /// figures end in `_wgpu`; with both, `learner_speedup_N` is the wgpu learner's updates
    /// per busy second over the CPU learner's, and `learner_rate_ratio_N` the same of their
    /// updates a second.
    #[arg(long, value_delimiter = ',')]
    learners: Vec<Backend>,
}

pub fn bench_e2e(args: &E2eBenchArgs) -> Result<()> {
    let logs = tempfile::tempdir()?;
    let mut figures = Map::new();
    figures.insert("episodes_per_run".into(), args.episodes.into());
    let runs = args.environments.iter().flat_map(|&environments| {
        args.envs_per_actor
            .iter()
            .filter(move |&&k| k > 0 && environments % k == 0)
            .map(move |&k| (environments, k))
    });
    // None: the config's own learner.
    let learners: Vec<Option<Backend>> = match args.learners.as_slice() {
        [] => vec![None],
        backends => backends.iter().copied().map(Some).collect(),
    };
    for (environments, k) in runs {
        let shape = match k {
            1 => format!("_{environments}"),
            k => format!("_{environments}_k{k}"),
        };
        let (mut cpu, mut gpu) = (None, None);
        for &backend in &learners {
            let mut settings = vec![format!("envs_per_actor={k}")];
            settings.extend(backend.map(|b| format!("backend.learner=\"{b}\"")));
            let (suffix, name) = match backend {
                Some(Backend::Wgpu) => (format!("{shape}_wgpu"), "-wgpu"),
                _ => (shape.clone(), ""),
            };
            let summary = train_run(
                Path::new(&args.config),
                environments / k,
                &settings,
                args.episodes.max(2 * u64::from(environments)),
                logs.path(),
                &format!("bench-e2e-{environments}-{k}{name}"),
            )?;
            let report = put_run(&mut figures, &summary, &suffix)?;
            match backend {
                Some(Backend::Cpu) => cpu = Some(report),
                Some(Backend::Wgpu) => gpu = Some(report),
                None => {}
            }
        }
        if let (Some(cpu), Some(gpu)) = (&cpu, &gpu) {
            let ratio = |pace: fn(&LearnerReport) -> Option<f64>| match (pace(gpu), pace(cpu)) {
                (Some(gpu), Some(cpu)) if cpu > 0.0 => round(gpu / cpu),
                _ => Value::Null,
            };
            figures.insert(
                format!("learner_speedup{shape}"),
                ratio(LearnerReport::updates_per_busy_s),
            );
            figures.insert(
                format!("learner_rate_ratio{shape}"),
                ratio(LearnerReport::updates_per_s),
            );
        }
    }
    print_figures(&Value::Object(figures), args.json)
}

/// One run's figures, their names ending in `suffix`; returns its learner's report.
fn put_run(
    figures: &mut Map<String, Value>,
    summary: &Value,
    suffix: &str,
) -> Result<LearnerReport> {
    let learner: LearnerReport = serde_json::from_value(summary["learner"].clone())
        .context("the learner's report in the run's summary")?;
    let mut put = |name: &str, value: f64| {
        figures.insert(format!("{name}{suffix}"), round(value));
    };
    put("actions_per_s", actions_per_s(summary));
    put(
        "learner_updates_per_s",
        learner.updates_per_s().unwrap_or(0.0),
    );
    put("learner_busy_share", learner.busy_share().unwrap_or(0.0));
    put(
        "learner_updates_per_busy_s",
        learner.updates_per_busy_s().unwrap_or(0.0),
    );
    // An update's busy time by part: which of them a faster backend has to shorten.
    let per_update_ms = |s: f64| 1e3 * s / (learner.session_updates.max(1) as f64);
    let parts = learner.step_s + learner.publish_s + learner.checkpoint_s;
    put("learner_step_ms_per_update", per_update_ms(learner.step_s));
    put(
        "learner_publish_ms_per_update",
        per_update_ms(learner.publish_s),
    );
    put(
        "learner_checkpoint_ms_per_update",
        per_update_ms(learner.checkpoint_s),
    );
    put(
        "learner_rest_ms_per_update",
        per_update_ms(learner.busy_s - parts),
    );
    let reports = summary["actors_reports"]
        .as_array()
        .map_or(&[][..], Vec::as_slice);
    let sum = |key: &str| -> f64 { reports.iter().map(|r| r[key].as_f64().unwrap_or(0.0)).sum() };
    put(
        "actor_cpu_ms_per_action",
        1e3 * sum("cpu_s") / sum("actions").max(1.0),
    );
    put(
        "learner_cpu_ms_per_update",
        1e3 * learner.cpu_s.unwrap_or(0.0) / (learner.session_updates.max(1) as f64),
    );
    put(
        "actor_peak_rss_mb_per_env",
        sum("peak_rss_mb") / (reports.len().max(1) as f64),
    );
    Ok(learner)
}

/// Runs `pushgrasp train` (processes over shared memory) into `logs/<name>-<pid>` and returns
/// its summary.
pub(super) fn train_run(
    config: &Path,
    actors: u32,
    settings: &[String],
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
        .args(settings.iter().flat_map(|s| ["--set", s]))
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

pub(super) fn round(x: f64) -> Value {
    ((x * 100.0).round() / 100.0).into()
}
