//! `pushgrasp bench soak`: memory over a long run. A real `train` run (processes over
//! shared memory) goes on until its replay is full, then `--minutes` more, while every
//! process's resident memory is sampled; each one's growth over the last three quarters of
//! that time (15 of the default 20 minutes) is printed beside the bound a long run must keep
//! (5%). Resident memory is split as the kernel counts it: the process's own (anonymous:
//! its heap, where a leak shows), pages of files it maps (its program's code, paged in as
//! new paths run) and shared memory it has touched (the topics' segments, bounded by their
//! sizes).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use serde_json::{Map, Value};

use super::e2e::round;
use super::{print_figures, status_mb};
use runtime::record::LAUNCHER_PROGRESS;
use runtime::supervisor::ProcessEntry;
use runtime::{RunDir, read_json};

/// The growth a process's memory may show over the measured window.
const BOUND_PCT: f64 = 5.0;

#[derive(Args)]
pub struct SoakBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// The run config.
    #[arg(long, default_value = "configs/stage3.toml")]
    config: PathBuf,
    /// Actor processes.
    #[arg(long, default_value_t = 2)]
    actors: u32,
    /// Each ring's capacity in steps (default: the config's), so that a replay fills sooner.
    #[arg(long)]
    capacity: Option<u64>,
    /// Minutes the run goes on once its replay is full.
    #[arg(long, default_value_t = 20.0)]
    minutes: f64,
    /// Seconds between samples of every process's memory.
    #[arg(long, default_value_t = 10.0)]
    every_s: f64,
    /// Minutes to wait for the replay to fill (both rings: a stage that trains one net
    /// never fills the other); the measured time starts then if it has not.
    #[arg(long, default_value_t = 60.0)]
    fill_timeout_min: f64,
}

pub fn bench_soak(args: &SoakBenchArgs) -> Result<()> {
    let scratch = tempfile::tempdir()?;
    let config = config_with_capacity(&args.config, args.capacity, scratch.path())?;
    let run_id = format!("soak-{}", std::process::id());
    let dir = RunDir::in_logs(scratch.path(), &run_id);
    let mut launcher = Command::new(std::env::current_exe()?)
        .arg("train")
        .arg("--config")
        .arg(&config)
        .args(["--actors", &args.actors.to_string()])
        .args(["--episodes", "1000000000", "--run-id", &run_id])
        .arg("--logs")
        .arg(scratch.path())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .context("starting train")?;
    let start = Instant::now();
    let every = Duration::from_secs_f64(args.every_s);
    let fill_timeout = Duration::from_secs_f64(args.fill_timeout_min * 60.0);
    let window = Duration::from_secs_f64(args.minutes * 60.0);
    let mut samples: Vec<(Duration, BTreeMap<String, Memory>)> = Vec::new();
    let mut full_at: Option<Duration> = None;
    let outcome = loop {
        if let Some(status) = launcher.try_wait()? {
            break Err(anyhow::anyhow!("the run ended by itself ({status})"));
        }
        let now = start.elapsed();
        let mut rss = BTreeMap::from([("launcher".to_string(), Memory::of(launcher.id()))]);
        if let Ok(entries) = read_json::<Vec<ProcessEntry>>(&dir.processes()) {
            for entry in entries {
                rss.insert(entry.role, Memory::of(entry.pid));
            }
        }
        samples.push((now, rss));
        if full_at.is_none() && (replay_full(&dir) || now > fill_timeout) {
            full_at = Some(now);
        }
        if full_at.is_some_and(|at| now >= at + window) {
            break Ok(());
        }
        std::thread::sleep(every);
    };
    // Ctrl-C: the run stops in order.
    let _ = Command::new("kill")
        .args(["-INT", &launcher.id().to_string()])
        .status();
    launcher.wait()?;
    outcome?;
    let full_at = full_at.expect("the loop ends after the fill");
    let mut figures = growth(&samples, full_at + window / 4, replay_full(&dir));
    figures.insert("fill_min".into(), round(full_at.as_secs_f64() / 60.0));
    figures.insert("measured_min".into(), round(args.minutes * 0.75));
    print_figures(&Value::Object(figures), args.json)
}

/// A process's resident memory (MB), whole and by kind (0 once it is gone).
#[derive(Clone, Copy)]
struct Memory {
    rss: f64,
    anon: f64,
    file: f64,
    shmem: f64,
}

impl Memory {
    fn of(pid: u32) -> Self {
        let field = |name| status_mb(&pid.to_string(), name).unwrap_or(0.0);
        Self {
            rss: field("VmRSS:"),
            anon: field("RssAnon:"),
            file: field("RssFile:"),
            shmem: field("RssShmem:"),
        }
    }
}

/// Each process's memory at the start of the measured window (the first sample from
/// `from`) and at the end, by kind, its growth, and the largest growth (resident, and
/// anonymous) beside the bound.
fn growth(
    samples: &[(Duration, BTreeMap<String, Memory>)],
    from: Duration,
    full: bool,
) -> Map<String, Value> {
    let window: Vec<&BTreeMap<String, Memory>> = samples
        .iter()
        .filter(|(at, _)| *at >= from)
        .map(|(_, rss)| rss)
        .collect();
    let mut figures = Map::new();
    figures.insert("replay_full".into(), full.into());
    let (mut most, mut most_anon) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    if let (Some(first), Some(last)) = (window.first(), window.last()) {
        for (process, end) in last.iter() {
            // A process started during the window (a restarted role) has no start figure.
            let Some(begin) = first.get(process).filter(|m| m.rss > 0.0) else {
                continue;
            };
            let pct = |begin: f64, end: f64| (end - begin) / begin * 100.0;
            most = most.max(pct(begin.rss, end.rss));
            most_anon = most_anon.max(pct(begin.anon, end.anon));
            figures.insert(
                format!("rss_growth_pct_{process}"),
                round(pct(begin.rss, end.rss)),
            );
            figures.insert(
                format!("anon_growth_pct_{process}"),
                round(pct(begin.anon, end.anon)),
            );
            let kinds = [
                ("rss", begin.rss, end.rss),
                ("anon", begin.anon, end.anon),
                ("file", begin.file, end.file),
                ("shmem", begin.shmem, end.shmem),
            ];
            for (kind, begin, end) in kinds {
                figures.insert(format!("{kind}_mb_{process}_start"), round(begin));
                figures.insert(format!("{kind}_mb_{process}_end"), round(end));
            }
        }
    }
    figures.insert("rss_growth_pct_max".into(), round(most));
    figures.insert("anon_growth_pct_max".into(), round(most_anon));
    figures.insert("rss_growth_pct_bound".into(), BOUND_PCT.into());
    figures
}

/// Whether the run's newest progress record shows its replay full (both rings).
fn replay_full(dir: &RunDir) -> bool {
    mcaplog::json_messages(dir.mcap("launcher"), LAUNCHER_PROGRESS)
        .ok()
        .and_then(|records| records.last().cloned())
        .is_some_and(|last| {
            let (stored, capacity) = (last["stored"].as_u64(), last["capacity"].as_u64());
            matches!((stored, capacity), (Some(s), Some(c)) if c > 0 && s >= c)
        })
}

/// `config`, or a copy of it in `scratch` with each ring holding `capacity` steps.
fn config_with_capacity(config: &Path, capacity: Option<u64>, scratch: &Path) -> Result<PathBuf> {
    let Some(capacity) = capacity else {
        return Ok(config.to_path_buf());
    };
    let text =
        std::fs::read_to_string(config).with_context(|| format!("reading {}", config.display()))?;
    let mut table: toml::Table =
        toml::from_str(&text).with_context(|| format!("{}", config.display()))?;
    let Some(buffer) = table.get_mut("buffer").and_then(|b| b.as_table_mut()) else {
        bail!("{} has no [buffer] table", config.display());
    };
    buffer.insert("capacity".into(), toml::Value::Integer(capacity as i64));
    let copy = scratch.join("soak.toml");
    std::fs::write(&copy, toml::to_string(&table)?)?;
    Ok(copy)
}
