//! `pushgrasp sweep summary <sweep-dir>`: one row per run (its axis values, episodes, final
//! goal grasp success, episodes to 80%, wall-clock) from its `summary.json` and `curve.csv`,
//! then the runs that differ only in their seed grouped, with the mean and spread of each
//! metric over the group's finished runs; as a table or one JSON object, and the runs'
//! success curves overlaid in a figure.
//!
//! Its tests take it past 400 lines; the code itself is under 400.

use std::cmp::Ordering;
use std::path::{Path, PathBuf};

use crate::group_by_all_but;
use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use serde::Serialize;
use stats::mean_and_spread;

use super::dir::{RunEntry, RunState, SweepDir};
use super::table;
use rundir::SUCCESS_WINDOW;

/// A run "reached 80%" at the first episode, from the 30th on, where at least this share of
/// its last 30 goal grasps succeeded, written as numerator / denominator to compare exactly
/// (0.8 x 30 in floating point is just above 24).
const TARGET: (usize, usize) = (4, 5);

#[derive(Args)]
pub struct SummaryArgs {
    /// The sweep directory (<logs>/<sweep name>).
    dir: PathBuf,
    /// Order of the runs: success (final goal grasp success, highest first; the default),
    /// episodes_to_80 (fewest first), wall_s (shortest first) or run (sweep order); runs
    /// without the figure come last.
    #[arg(long, value_enum, default_value_t = SortKey::Success)]
    sort: SortKey,
    /// Overlay the runs' goal grasp success curves in this file (.png or .svg).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Print the rows and the groups as one JSON object.
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "snake_case")]
enum SortKey {
    Success,
    #[value(name = "episodes_to_80")]
    EpisodesTo80,
    #[value(name = "wall_s")]
    WallS,
    Run,
}

/// One run's figures; `None` where the run has not written them.
#[derive(Debug, Serialize)]
struct Row {
    run: String,
    /// The keys the sweep sets in this run.
    values: serde_json::Map<String, serde_json::Value>,
    state: String,
    episodes: Option<u64>,
    /// Goal grasp success over the last 30 episodes, as a share.
    success_last30: Option<f64>,
    episodes_to_80: Option<u64>,
    /// Wall-clock seconds of the run's last session (`train` counts per session).
    wall_s: Option<f64>,
    #[serde(skip)]
    done: bool,
    /// Episode and success over the last 30, from `curve.csv`.
    #[serde(skip)]
    curve: Vec<(u64, f64)>,
}

/// The mean and sample standard deviation of one metric over `n` runs.
#[derive(Debug, Serialize)]
struct Stat {
    mean: f64,
    spread: f64,
    n: usize,
}

/// Runs that differ only in their seed.
#[derive(Debug, Serialize)]
struct Group {
    /// The overrides the group's runs share; empty when the seed is the only axis.
    label: String,
    runs: Vec<String>,
    /// Runs done: only they enter the statistics.
    done: usize,
    episodes: Option<Stat>,
    success_last30: Option<Stat>,
    /// Over the runs that reached 80%; `reached_80` says how many did.
    episodes_to_80: Option<Stat>,
    reached_80: usize,
    wall_s: Option<Stat>,
}

#[derive(Serialize)]
struct Report {
    sweep: String,
    sort: SortKey,
    runs: Vec<Row>,
    groups: Vec<Group>,
}

pub fn print(args: &SummaryArgs) -> Result<()> {
    let dir = SweepDir::open(&args.dir)?;
    let state = dir.read_state()?;
    let plans = dir.plans(&state)?;
    let mut rows = Vec::with_capacity(state.runs.len());
    for entry in &state.runs {
        rows.push(row(&dir, entry)?);
    }
    let groups: Vec<Group> = group_by_all_but(&plans, "seed")
        .into_iter()
        .map(|(label, indices)| group(label, indices.iter().map(|&i| &rows[i])))
        .collect();
    sort(&mut rows, args.sort);
    if let Some(path) = &args.plot {
        plot(&rows, path)?;
    }
    let report = Report {
        sweep: state.name,
        sort: args.sort,
        runs: rows,
        groups,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_text(&report);
        if let Some(path) = &args.plot {
            println!("success curves drawn to {}", path.display());
        }
    }
    Ok(())
}

fn row(dir: &SweepDir, entry: &RunEntry) -> Result<Row> {
    let summary = dir.summary(&entry.id)?;
    let curve_path = dir.run_dir(&entry.id).curve();
    let outcomes = if curve_path.exists() {
        read_curve(&curve_path)?
    } else {
        Vec::new()
    };
    let values = entry
        .overrides
        .iter()
        .map(|(key, value)| Ok((key.clone(), serde_json::to_value(value)?)))
        .collect::<Result<_>>()?;
    let state = dir.run_state(entry)?;
    Ok(Row {
        run: entry.id.clone(),
        values,
        state: state.to_string(),
        episodes: summary.as_ref().map(|s| s.buffer.episodes),
        success_last30: summary.as_ref().and_then(|s| s.buffer.success_last30),
        episodes_to_80: episodes_to_80(&outcomes),
        wall_s: summary.as_ref().map(|s| s.wall_s),
        done: state == RunState::Done,
        curve: outcomes
            .iter()
            .map(|&(episode, _, success)| (episode, success))
            .collect(),
    })
}

/// `curve.csv`: per episode, its number, whether the goal was grasped and the success over
/// the last 30.
fn read_curve(path: &Path) -> Result<Vec<(u64, bool, f64)>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, "episode,goal_grasped,success_last30")) => {}
        _ => bail!(
            "{}: expected the header episode,goal_grasped,success_last30",
            path.display()
        ),
    }
    lines
        .filter(|(_, line)| !line.is_empty())
        .map(|(number, line)| {
            curve_line(line)
                .with_context(|| format!("{} line {}: {line:?}", path.display(), number + 1))
        })
        .collect()
}

fn curve_line(line: &str) -> Option<(u64, bool, f64)> {
    let mut fields = line.split(',');
    let episode = fields.next()?.parse().ok()?;
    let grasped = match fields.next()? {
        "0" => false,
        "1" => true,
        _ => return None,
    };
    let success = fields.next()?.parse().ok()?;
    fields
        .next()
        .is_none()
        .then_some((episode, grasped, success))
}

/// The first episode from the 30th on where the last 30 goal grasps reached the target
/// share; counted from the outcomes, not from the rounded success column.
fn episodes_to_80(outcomes: &[(u64, bool, f64)]) -> Option<u64> {
    let mut in_window = 0;
    for (i, &(episode, grasped, _)) in outcomes.iter().enumerate() {
        in_window += usize::from(grasped);
        if i >= SUCCESS_WINDOW {
            in_window -= usize::from(outcomes[i - SUCCESS_WINDOW].1);
        }
        if i + 1 >= SUCCESS_WINDOW && in_window * TARGET.1 >= TARGET.0 * SUCCESS_WINDOW {
            return Some(episode);
        }
    }
    None
}

fn group<'a>(label: String, rows: impl Iterator<Item = &'a Row>) -> Group {
    let rows: Vec<&Row> = rows.collect();
    let done: Vec<&Row> = rows.iter().copied().filter(|r| r.done).collect();
    let stat = |metric: &dyn Fn(&Row) -> Option<f64>| {
        let values: Vec<f64> = done.iter().filter_map(|r| metric(r)).collect();
        mean_and_spread(&values).map(|(mean, spread)| Stat {
            mean,
            spread,
            n: values.len(),
        })
    };
    Group {
        label,
        runs: rows.iter().map(|r| r.run.clone()).collect(),
        done: done.len(),
        episodes: stat(&|r| r.episodes.map(|n| n as f64)),
        success_last30: stat(&|r| r.success_last30),
        episodes_to_80: stat(&|r| r.episodes_to_80.map(|n| n as f64)),
        reached_80: done.iter().filter(|r| r.episodes_to_80.is_some()).count(),
        wall_s: stat(&|r| r.wall_s),
    }
}

/// Sorts by `key`, best first, runs without the figure last; ties keep sweep order.
fn sort(rows: &mut [Row], key: SortKey) {
    let figure = |row: &Row| -> Option<f64> {
        match key {
            // Negated: the highest success first.
            SortKey::Success => row.success_last30.map(|s| -s),
            SortKey::EpisodesTo80 => row.episodes_to_80.map(|n| n as f64),
            SortKey::WallS => row.wall_s,
            SortKey::Run => Some(0.0),
        }
    };
    // A stable sort: equal figures stay in sweep order.
    rows.sort_by(|a, b| match (figure(a), figure(b)) {
        (Some(x), Some(y)) => x.total_cmp(&y),
        (Some(_), None) => Ordering::Less,
        (None, Some(_)) => Ordering::Greater,
        (None, None) => Ordering::Equal,
    });
}

fn plot(rows: &[Row], path: &Path) -> Result<()> {
    let series: Vec<plots::Series> = rows
        .iter()
        .filter(|row| !row.curve.is_empty())
        .map(|row| plots::Series {
            label: row.run.clone(),
            points: row
                .curve
                .iter()
                .map(|&(episode, success)| (episode as f64, 100.0 * success))
                .collect(),
        })
        .collect();
    if series.is_empty() {
        bail!("--plot: no run has a curve.csv yet");
    }
    let chart = plots::Chart {
        title: format!("Goal grasp success (last {SUCCESS_WINDOW} episodes)"),
        x_label: "episodes".into(),
        y_label: "%".into(),
        series,
        references: vec![(100.0 * TARGET.0 as f64 / TARGET.1 as f64, "80%".into())],
        y_range: Some((0.0, 100.0)),
    };
    plots::draw(&[chart], 1, path)?;
    Ok(())
}

fn print_text(report: &Report) {
    let sort = match report.sort {
        SortKey::Success => "final success, highest first",
        SortKey::EpisodesTo80 => "episodes to 80%, fewest first",
        SortKey::WallS => "wall-clock, shortest first",
        SortKey::Run => "sweep order",
    };
    println!(
        "sweep {}: {} runs, by {sort}",
        report.sweep,
        report.runs.len()
    );
    let keys: Vec<String> = report
        .runs
        .first()
        .map(|row| row.values.keys().cloned().collect())
        .unwrap_or_default();
    let mut header = vec!["run".to_string()];
    header.extend(keys.iter().cloned());
    header.extend(
        [
            "state",
            "episodes",
            "success (last 30)",
            "episodes to 80%",
            "wall",
        ]
        .map(String::from),
    );
    let rows: Vec<Vec<String>> = report
        .runs
        .iter()
        .map(|row| {
            let mut cells = vec![row.run.clone()];
            cells.extend(keys.iter().map(|key| {
                row.values
                    .get(key)
                    .map_or("-".to_string(), ToString::to_string)
            }));
            cells.extend([
                row.state.clone(),
                show(row.episodes),
                row.success_last30.map_or("-".into(), percent),
                show(row.episodes_to_80),
                row.wall_s.map_or("-".into(), |s| format!("{s:.0} s")),
            ]);
            cells
        })
        .collect();
    print!("{}", table::render(&header, &rows));

    // Groups of one run would only repeat the rows.
    if report.groups.iter().all(|g| g.runs.len() < 2) {
        return;
    }
    println!("\nover seeds: mean ± sample standard deviation over each group's done runs");
    let header = [
        "group",
        "done",
        "episodes",
        "success (last 30)",
        "episodes to 80%",
        "wall",
    ]
    .map(String::from);
    let rows: Vec<Vec<String>> = report
        .groups
        .iter()
        .map(|g| {
            let stat = |s: &Option<Stat>, format: &dyn Fn(f64) -> String| {
                s.as_ref().map_or("-".into(), |s| {
                    format!("{} ± {}", format(s.mean), format(s.spread))
                })
            };
            vec![
                if g.label.is_empty() {
                    "(all runs)".to_string()
                } else {
                    g.label.clone()
                },
                format!("{}/{}", g.done, g.runs.len()),
                stat(&g.episodes, &|x| format!("{x:.0}")),
                stat(&g.success_last30, &percent),
                format!(
                    "{} ({} reached)",
                    stat(&g.episodes_to_80, &|x| format!("{x:.0}")),
                    g.reached_80
                ),
                stat(&g.wall_s, &|x| format!("{x:.0} s")),
            ]
        })
        .collect();
    print!("{}", table::render(&header, &rows));
}

fn show(n: Option<u64>) -> String {
    n.map_or("-".into(), |n| n.to_string())
}

fn percent(share: f64) -> String {
    format!("{:.1}%", 100.0 * share)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn outcomes(grasped: &[bool]) -> Vec<(u64, bool, f64)> {
        grasped
            .iter()
            .enumerate()
            .map(|(i, &g)| (i as u64 + 1, g, 0.0))
            .collect()
    }

    #[test]
    fn eighty_percent_is_reached_at_24_of_the_last_30() {
        // 6 failures, then successes: the window of episodes 1..=30 holds 24.
        let mut grasped = vec![false; 6];
        grasped.extend([true; 40]);
        assert_eq!(episodes_to_80(&outcomes(&grasped)), Some(30));
        // 7 failures first: 23 of the first 30, 24 of episodes 2..=31.
        let mut grasped = vec![false; 7];
        grasped.extend([true; 40]);
        assert_eq!(episodes_to_80(&outcomes(&grasped)), Some(31));
    }

    #[test]
    fn eighty_percent_needs_30_episodes() {
        assert_eq!(episodes_to_80(&outcomes(&[true; 29])), None);
        assert_eq!(episodes_to_80(&outcomes(&[true; 30])), Some(30));
        // Alternating: never more than half.
        let alternating: Vec<bool> = (0..100).map(|i| i % 2 == 0).collect();
        assert_eq!(episodes_to_80(&outcomes(&alternating)), None);
    }
}
