//! `pushgrasp bench soak`: memory over a long run. A real `train` run (processes over
//! shared memory) goes on until its replay is full, then `--minutes` more, while every
//! process's resident memory is sampled; each one's growth over the last three quarters of
//! that time (15 of the default 20 minutes; each end the median of its tenth of that
//! window, so that a transient peak is not read as growth) is printed beside the bound a
//! long run must keep (5%). Resident memory is split as the kernel counts it: the process's
//! own (anonymous: its heap, where a leak shows), pages of files it maps (its program's code,
//! paged in as new paths run) and shared memory it has touched (the topics' segments,
//! bounded by their sizes). End against start does not tell a plateau from a ratchet, so
//! each process's slope over the last third of the window is printed too, and whether it
//! still grows. Each process's own log of its live bytes (what the program holds allocated)
//! gives the same figures of those: live bytes that stay level under a resident rise are
//! the allocator's keep, not the program's data.
//!
//! Its tests take it past 400 lines; the code itself is under 400.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use serde_json::{Map, Value};

use super::e2e::round;
use super::{print_figures, status_mb};
use rundir::ProcessEntry;
use rundir::record::{LAUNCHER_PROGRESS, PROCESS_MEMORY};
use rundir::{RunDir, read_json};
use runtime::memory::MemoryRecord;

/// The growth a process's memory may show over the measured window.
const BOUND_PCT: f64 = 5.0;

/// A process whose fitted rise over the last third of the window is less than this share
/// of its resident memory has levelled off; more, and it still grows.
const LEVEL_PCT: f64 = 1.0;

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
    /// Also write every sample to this CSV file (`at_s,process,kind,mb`; kinds rss, anon,
    /// file, shmem and live), to plot the curves.
    #[arg(long)]
    series: Option<PathBuf>,
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
    let (start, start_ns) = (Instant::now(), mcaplog::now_ns());
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
    let mut live = BTreeMap::new();
    if let Some((_, last)) = samples.last() {
        for process in last.keys() {
            live.insert(process.clone(), live_series(&dir, process, start_ns)?);
        }
    }
    if let Some(path) = &args.series {
        write_series(path, &samples, &live)?;
    }
    let mut figures = growth(&samples, &live, full_at + window / 4, replay_full(&dir));
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

/// A process's live bytes over the soak, from its log's memory records (every segment):
/// (seconds since the soak began, MB).
fn live_series(dir: &RunDir, process: &str, start_ns: u64) -> Result<Vec<(f64, f64)>> {
    let mut series = Vec::new();
    for path in mcaplog::segments(&dir.mcap(process)) {
        let records = mcaplog::timed_json_messages(&path, PROCESS_MEMORY)?;
        for (ns, value) in records {
            let record = serde_json::from_value::<MemoryRecord>(value)
                .with_context(|| format!("a memory record in {}", path.display()))?;
            let at_s = ns.saturating_sub(start_ns) as f64 * 1e-9;
            series.extend(record.live_mb.map(|mb| (at_s, mb)));
        }
    }
    Ok(series)
}

/// Every sample as a row of `at_s,process,kind,mb`.
fn write_series(
    path: &Path,
    samples: &[(Duration, BTreeMap<String, Memory>)],
    live: &BTreeMap<String, Vec<(f64, f64)>>,
) -> Result<()> {
    let mut rows = vec!["at_s,process,kind,mb".to_string()];
    for (at, processes) in samples {
        for (process, m) in processes {
            let kinds = [
                ("rss", m.rss),
                ("anon", m.anon),
                ("file", m.file),
                ("shmem", m.shmem),
            ];
            for (kind, mb) in kinds {
                rows.push(format!("{:.1},{process},{kind},{mb:.3}", at.as_secs_f64()));
            }
        }
    }
    for (process, series) in live {
        rows.extend(
            series
                .iter()
                .map(|(at_s, mb)| format!("{at_s:.1},{process},live,{mb:.3}")),
        );
    }
    rows.push(String::new());
    std::fs::write(path, rows.join("\n")).with_context(|| format!("writing {}", path.display()))
}

/// Each process's memory at the start and at the end of the measured window (from `from` to
/// the last sample), by kind: resident (`rss`) and its anonymous, file and shared parts, and
/// the live bytes it logged itself (`live`, seconds and MB), which tell data it keeps from
/// freed memory its allocator keeps. Memory swings within a step (a learner's by tens of MB,
/// an actor's by a few), so each end is the median of its tenth of the window, and a single
/// sample at a peak is not read as growth. Then the growth, the slope over the last third
/// and whether it still grows, and the largest growth of each kind beside the bound.
fn growth(
    samples: &[(Duration, BTreeMap<String, Memory>)],
    live: &BTreeMap<String, Vec<(f64, f64)>>,
    from: Duration,
    full: bool,
) -> Map<String, Value> {
    let mut figures = Map::new();
    figures.insert("replay_full".into(), full.into());
    let window: Vec<(f64, &BTreeMap<String, Memory>)> = samples
        .iter()
        .filter(|(at, _)| *at >= from)
        .map(|(at, memory)| (at.as_secs_f64(), memory))
        .collect();
    let (Some(&(first_s, first)), Some(&(last_s, last))) = (window.first(), window.last()) else {
        return figures;
    };
    let mut most: BTreeMap<&str, f64> = BTreeMap::new();
    for process in last.keys() {
        // A process started during the window (a restarted role) has no start figure.
        if first.get(process).is_none_or(|m| m.rss <= 0.0) {
            continue;
        }
        let sampled = |kind: fn(&Memory) -> f64| -> Vec<(f64, f64)> {
            window
                .iter()
                .filter_map(|(at_s, memory)| Some((*at_s, kind(memory.get(process)?))))
                .collect()
        };
        // A role logs its memory once more as it ends, its state dropped: not the run's.
        let logged: Vec<(f64, f64)> = live
            .get(process)
            .into_iter()
            .flatten()
            .copied()
            .filter(|&(at_s, _)| (first_s..=last_s).contains(&at_s))
            .collect();
        let kinds = [
            ("rss", sampled(|m| m.rss)),
            ("anon", sampled(|m| m.anon)),
            ("file", sampled(|m| m.file)),
            ("shmem", sampled(|m| m.shmem)),
            ("live", logged),
        ];
        for (kind, series) in kinds {
            let tenth = series.len().div_ceil(10);
            let (Some(begin), Some(end)) = (
                median(series.iter().take(tenth).map(|p| p.1)),
                median(series.iter().rev().take(tenth).map(|p| p.1)),
            ) else {
                continue;
            };
            figures.insert(format!("{kind}_mb_{process}_start"), round(begin));
            figures.insert(format!("{kind}_mb_{process}_end"), round(end));
            if matches!(kind, "file" | "shmem") {
                continue;
            }
            let pct = (end - begin) / begin * 100.0;
            let largest = most.entry(kind).or_insert(f64::NEG_INFINITY);
            *largest = largest.max(pct);
            figures.insert(format!("{kind}_growth_pct_{process}"), round(pct));
            if kind == "anon" {
                continue;
            }
            let (per_h, grows) = last_third(&series);
            let prefix = if kind == "live" { "live_" } else { "" };
            figures.insert(
                format!("{kind}_mb_per_h_last_third_{process}"),
                round(per_h),
            );
            figures.insert(format!("{prefix}still_grows_{process}"), grows.into());
        }
    }
    for (kind, largest) in most {
        figures.insert(format!("{kind}_growth_pct_max"), round(largest));
    }
    figures.insert("rss_growth_pct_bound".into(), BOUND_PCT.into());
    figures
}

fn median(values: impl Iterator<Item = f64>) -> Option<f64> {
    let mut values: Vec<f64> = values.collect();
    values.sort_by(f64::total_cmp);
    let n = values.len();
    (n > 0).then(|| (values[(n - 1) / 2] + values[n / 2]) / 2.0)
}

/// The least-squares slope (MB an hour) of resident memory over the last third of a series
/// of (seconds, MB), and whether the rise it fits over that third is past [`LEVEL_PCT`] of
/// the memory: a ratchet still climbs there, a plateau does not.
fn last_third(series: &[(f64, f64)]) -> (f64, bool) {
    let Some(&(end, _)) = series.last() else {
        return (0.0, false);
    };
    let begin = series[0].0 + (end - series[0].0) * 2.0 / 3.0;
    let third: Vec<(f64, f64)> = series
        .iter()
        .copied()
        .filter(|&(t, _)| t >= begin)
        .collect();
    let n = third.len() as f64;
    if third.len() < 2 {
        return (0.0, false);
    }
    let (mean_t, mean_mb) = (
        third.iter().map(|p| p.0).sum::<f64>() / n,
        third.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let covariance: f64 = third
        .iter()
        .map(|(t, mb)| (t - mean_t) * (mb - mean_mb))
        .sum();
    let variance: f64 = third.iter().map(|(t, _)| (t - mean_t).powi(2)).sum();
    let per_s = if variance > 0.0 {
        covariance / variance
    } else {
        0.0
    };
    let rise = per_s * (end - begin);
    (per_s * 3600.0, rise > mean_mb * LEVEL_PCT / 100.0)
}

/// Whether the run's newest progress record shows its replay full (both rings).
fn replay_full(dir: &RunDir) -> bool {
    mcaplog::newest_json_message(dir.mcap("launcher"), LAUNCHER_PROGRESS)
        .ok()
        .flatten()
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

#[cfg(test)]
mod tests {
    use super::*;

    /// 15 minutes sampled every 10 s: a rise of 10 MB in the first third, then `then`.
    fn series(then: impl Fn(f64) -> f64) -> Vec<(f64, f64)> {
        (0..=90)
            .map(|i| {
                let t = f64::from(i) * 10.0;
                let early = 10.0 * (t / 300.0).min(1.0);
                (t, 100.0 + early + then(t))
            })
            .collect()
    }

    /// 15 minutes of one actor's memory, sampled every 10 s, resident `rss(i)` at sample i;
    /// its live bytes steady at 16 MB.
    fn soak(rss: impl Fn(u64) -> f64) -> Map<String, Value> {
        let process = "actor-0-0".to_string();
        let samples: Vec<(Duration, BTreeMap<String, Memory>)> = (0..=90)
            .map(|i| {
                let memory = Memory {
                    rss: rss(i),
                    anon: rss(i) - 20.0,
                    file: 15.0,
                    shmem: 2.0,
                };
                (
                    Duration::from_secs(i * 10),
                    BTreeMap::from([(process.clone(), memory)]),
                )
            })
            .collect();
        let live = (0..=90).map(|i| (i as f64 * 10.0, 16.0)).collect();
        growth(
            &samples,
            &BTreeMap::from([(process, live)]),
            Duration::ZERO,
            true,
        )
    }

    #[test]
    fn a_peak_is_not_growth_and_a_step_is() {
        // One sample at a transient peak, at the very end.
        let peak = soak(|i| if i == 90 { 46.0 } else { 42.0 });
        assert_eq!(peak["rss_growth_pct_actor-0-0"], 0.0);
        assert_eq!(peak["live_growth_pct_max"], 0.0);
        // 4 MB more for the last fifth of the window: grown, by 9.5%.
        let step = soak(|i| if i >= 72 { 46.0 } else { 42.0 });
        let pct = step["rss_growth_pct_actor-0-0"].as_f64().unwrap();
        assert!((pct - 9.52).abs() < 0.01, "{pct}");
        assert_eq!(step["rss_growth_pct_max"], step["rss_growth_pct_actor-0-0"]);
        assert_eq!(step["anon_mb_actor-0-0_end"], 26.0);
    }

    #[test]
    fn a_plateau_and_a_ratchet_read_differently() {
        let (per_h, grows) = last_third(&series(|_| 0.0));
        assert!(per_h.abs() < 1e-9 && !grows);
        // 2 MB steps every 100 s from the start: 6 MB over the last third.
        let (per_h, grows) = last_third(&series(|t| 2.0 * (t / 100.0).floor()));
        assert!((per_h - 72.0).abs() < 8.0 && grows, "{per_h}");
        // Half a megabyte near the end of a 110 MB process: a fitted rise under 1%.
        let (_, grows) = last_third(&series(|t| if t > 800.0 { 0.5 } else { 0.0 }));
        assert!(!grows);
    }
}
