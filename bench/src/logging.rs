//! `pushgrasp bench logging`: what the MCAP logs cost. Actor throughput of real training runs
//! with logging on and off, alternated in the same invocation (so drift hits both), and the
//! bytes a run's logs take per episode at 224 x 224, scaled to 1000 episodes.
//!
//! The runs lift the rate limiter (a huge error buffer), so the actors act at their own pace
//! instead of the learner's: the figure is what logging takes from an actor.

use std::path::Path;

use anyhow::{Context, Result};
use clap::Args;
use serde_json::{Map, Value};

use super::e2e::{actions_per_s, round, train_run};
use super::print_figures;
use rundir::config::RunConfig;
use rundir::files_with_extension;

#[derive(Args)]
pub struct LoggingBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// The run config the runs start from.
    #[arg(long, default_value = "configs/stage1.toml")]
    config: String,
    /// Episodes per throughput run.
    #[arg(long, default_value_t = 60)]
    episodes: u64,
    /// Pairs of runs (on, off) for the throughput figures.
    #[arg(long, default_value_t = 2)]
    rounds: u32,
    /// Episodes of the run whose logs are weighed, at 224 x 224.
    #[arg(long, default_value_t = 30)]
    size_episodes: u64,
}

/// Heightmap side of the size figure.
const SIZE_SIDE: usize = 224;

pub fn bench_logging(args: &LoggingBenchArgs) -> Result<()> {
    let base = RunConfig::load(Path::new(&args.config))?;
    let work = tempfile::tempdir()?;
    let write = |name: &str, config: &RunConfig| -> Result<std::path::PathBuf> {
        let path = work.path().join(format!("{name}.toml"));
        std::fs::write(&path, toml::to_string(config)?)
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(path)
    };
    let variant = |enabled: bool| {
        let mut config = base.clone();
        config.logging.enabled = enabled;
        config.buffer.error_buffer = 1e12;
        config
    };
    let on = write("on", &variant(true))?;
    let off = write("off", &variant(false))?;

    let (mut with, mut without) = (Vec::new(), Vec::new());
    for round in 0..args.rounds.max(1) {
        // On first in even rounds, off first in odd ones.
        let order = if round % 2 == 0 {
            [true, false]
        } else {
            [false, true]
        };
        for enabled in order {
            let (config, name, figures) = if enabled {
                (&on, "bench-log-on", &mut with)
            } else {
                (&off, "bench-log-off", &mut without)
            };
            let summary = train_run(config, 1, &[], args.episodes, work.path(), name)?;
            figures.push(actions_per_s(&summary));
            let _ = std::fs::remove_dir_all(work.path().join(summary_run_id(&summary)));
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (on_rate, off_rate) = (mean(&with), mean(&without));

    // The logs of a run at 224 x 224, weighed.
    let mut sized = variant(true);
    sized.sim.pixel_size = base.sim.pixel_size * base.side() as f32 / SIZE_SIDE as f32;
    let sized_path = write("sized", &sized)?;
    let summary = train_run(
        &sized_path,
        1,
        &[],
        args.size_episodes,
        work.path(),
        "bench-log-size",
    )?;
    let dir = work.path().join(summary_run_id(&summary));
    let mut bytes = 0u64;
    for path in files_with_extension(&dir, "mcap")? {
        bytes += std::fs::metadata(&path)?.len();
    }
    let episodes = summary["buffer"]["episodes"].as_u64().unwrap_or(0).max(1);

    let mut figures = Map::new();
    figures.insert("episodes_per_run".into(), args.episodes.into());
    figures.insert("runs_per_setting".into(), with.len().into());
    figures.insert("actions_per_s_logging_on".into(), round(on_rate));
    figures.insert("actions_per_s_logging_off".into(), round(off_rate));
    figures.insert(
        "logging_overhead_pct".into(),
        round(100.0 * (1.0 - on_rate / off_rate)),
    );
    figures.insert("size_side".into(), SIZE_SIDE.into());
    figures.insert("size_run_episodes".into(), episodes.into());
    figures.insert(
        "log_kb_per_episode_224".into(),
        round(bytes as f64 / episodes as f64 / 1e3),
    );
    figures.insert(
        "log_mb_per_1000_episodes_224".into(),
        round(bytes as f64 / episodes as f64 * 1000.0 / 1e6),
    );
    print_figures(&Value::Object(figures), args.json)
}

fn summary_run_id(summary: &Value) -> String {
    summary["run_id"].as_str().unwrap_or_default().to_string()
}
