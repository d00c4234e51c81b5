//! `pushgrasp inspect`: what a run's MCAP logs say, without custom tools: the files and
//! processes (counts, time spans, whether one had to be recovered), the run's config, the
//! paper's metric and the learner's and buffer's curves (as tables, `--json` or a `--plot`),
//! an episode table, and one episode's pictures (`--episode K --export DIR`). Several runs at
//! once overlay their curves; a pipeline directory's stages join into one line, episodes,
//! actions and updates counting on from stage to stage. `pushgrasp logs recover` rewrites a
//! file cut short by a crash.
//!
//! The report, its printing and its charts read the same runs in one pass, so they stay in one file
//! at just over 400 lines.

mod export;
mod run;

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use serde::Serialize;

use run::{EpisodeRow, FileReport, Run, pipeline_stages};
use rundir::SUCCESS_WINDOW;

#[derive(Args)]
pub struct InspectArgs {
    /// Run directories (every .mcap in each), pipeline directories (their stages joined into
    /// one line) or .mcap files; several overlay their curves.
    #[arg(required = true)]
    paths: Vec<PathBuf>,
    /// Print one JSON object per run (an array for several) instead of tables.
    #[arg(long)]
    json: bool,
    /// Draw the curves to this file (.png or .svg).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Print every episode, not only the last 10.
    #[arg(long)]
    episodes: bool,
    /// The episode (numbered as in the episode table) to `--export`.
    #[arg(long, requires = "export")]
    episode: Option<usize>,
    /// Write the episode's pictures (PNG) and steps (JSON) into this directory.
    #[arg(long, requires = "episode")]
    export: Option<PathBuf>,
}

#[derive(Subcommand)]
pub enum LogsCommand {
    /// Rewrite an MCAP file cut short (a killed process) as a valid one, keeping every
    /// complete chunk.
    Recover {
        file: PathBuf,
        /// Where to write it (default: <file>.recovered.mcap beside it).
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

/// The figures `--json` prints for a run.
#[derive(Serialize)]
struct RunReport<'a> {
    run: &'a str,
    files: &'a [FileReport],
    /// Episode ends the buffer took in.
    episodes: u64,
    /// Grasps the actors shipped.
    grasp_attempts: u64,
    /// Goal grasp success over the run's last 30 episodes (the paper's metric).
    goal_grasp_success_last30: Option<f64>,
    /// Steps the actors logged as sent, and the buffer's last count of those received.
    steps_sent: u64,
    steps_received: Option<u64>,
    learner_updates: Option<u64>,
    /// Actions (steps) of the episodes the buffer took in.
    actions: u64,
    /// Goal grasp success over the last 30 episodes, every 10 episodes.
    curve: Vec<(u64, f64)>,
    /// The same curve against the actions taken by then.
    curve_by_actions: Vec<(u64, f64)>,
    /// Mean predicted Q of the goal grasps among the last 30 episodes, every 10 episodes.
    goal_grasp_q: Vec<(u64, f64)>,
    /// Share of the buffer's transitions that are relabelled copies, by episodes taken in.
    relabelled_share: Vec<(u64, f64)>,
    /// Learner loss per primitive, averaged over windows of up to 50 updates.
    loss: Vec<(String, Vec<(u64, f64)>)>,
}

impl<'a> RunReport<'a> {
    fn new(run: &'a Run) -> Self {
        let curve = run.success_curve();
        let actions = run.actions_by_episode();
        let curve_by_actions = curve
            .iter()
            .map(|&(episode, success)| (actions[episode as usize - 1], success))
            .collect();
        RunReport {
            run: &run.name,
            files: &run.files,
            episodes: run.episodes.len() as u64,
            grasp_attempts: run
                .steps
                .iter()
                .filter(|(_, s)| s.primitive == "grasp")
                .count() as u64,
            goal_grasp_success_last30: curve.last().map(|&(_, s)| s),
            steps_sent: run.steps.len() as u64,
            steps_received: run.buffer.last().map(|b| b.steps_received),
            learner_updates: run.updates.last().map(|u| u.updates),
            actions: actions.last().copied().unwrap_or(0),
            curve,
            curve_by_actions,
            goal_grasp_q: run.goal_grasp_q_curve(),
            relabelled_share: run.relabelled_curve(),
            loss: run.loss_curves(),
        }
    }
}

/// One line of the plots: a run, or a pipeline's stages joined.
struct Line {
    label: String,
    /// Indices into the runs, in stage order.
    runs: Vec<usize>,
}

pub fn inspect(args: &InspectArgs) -> Result<()> {
    let mut runs = Vec::new();
    let mut lines = Vec::new();
    for path in &args.paths {
        let stages = pipeline_stages(path);
        let label = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into(),
        );
        let first = runs.len();
        if stages.is_empty() {
            runs.push(Run::read(path)?);
        } else {
            for stage in &stages {
                let mut run = Run::read(stage)?;
                run.name = format!("{label}/{}", run.name);
                runs.push(run);
            }
        }
        lines.push(Line {
            label,
            runs: (first..runs.len()).collect(),
        });
    }
    if let (Some(number), Some(dir)) = (args.episode, &args.export) {
        let [run] = runs.as_slice() else {
            bail!(
                "--episode and --export take one run (a stage's directory), not {}",
                runs.len()
            );
        };
        let written = export::export_episode(run, number, dir)?;
        println!(
            "episode {number}: {} files written to {}",
            written.len(),
            dir.display()
        );
        return Ok(());
    }
    let reports: Vec<RunReport> = runs.iter().map(RunReport::new).collect();
    if let Some(path) = &args.plot {
        plots::draw(&charts(&runs, &reports, &lines), 2, path)?;
    }
    if args.json {
        let json = match reports.as_slice() {
            [one] => serde_json::to_string(one)?,
            all => serde_json::to_string(all)?,
        };
        println!("{json}");
        return Ok(());
    }
    for (run, report) in runs.iter().zip(&reports) {
        print_run(run, report, args.episodes);
    }
    if let Some(path) = &args.plot {
        println!("curves drawn to {}", path.display());
    }
    Ok(())
}

fn print_run(run: &Run, report: &RunReport, all_episodes: bool) {
    println!("== {}", run.name);
    for f in &run.files {
        println!(
            "{}: {}{} ({} messages over {}){}",
            f.file,
            f.process.as_deref().unwrap_or("?"),
            f.device
                .as_ref()
                .map_or(String::new(), |d| format!(", nets on {d}")),
            f.messages,
            f.span_s.map_or("-".into(), |s| format!("{s:.1} s")),
            if f.recovered {
                format!(" (recovered: {})", f.damage.join("; "))
            } else {
                String::new()
            }
        );
        for (topic, n) in &f.channels {
            println!("  {topic:28} {n:>9}");
        }
    }
    if let Some(c) = &run.config {
        println!(
            "config: stage {}, seed {}, {} objects, {} actors, {} episodes, {} px, Q* {}",
            c.stage,
            c.seed,
            c.objects,
            c.actors,
            c.episodes,
            c.side(),
            c.policy.q_star
        );
    }
    let show = |x: Option<u64>| x.map_or("-".into(), |x| x.to_string());
    println!(
        "episodes {}  grasp attempts {}  steps sent {}  received {}  learner updates {}",
        report.episodes,
        report.grasp_attempts,
        report.steps_sent,
        show(report.steps_received),
        show(report.learner_updates)
    );
    if !report.curve.is_empty() {
        println!(
            "episode  goal grasp success (last {SUCCESS_WINDOW})  Q of goal grasps  relabelled"
        );
        for &(episode, success) in &report.curve {
            let q = report
                .goal_grasp_q
                .iter()
                .find(|p| p.0 == episode)
                .map_or("-".into(), |p| format!("{:.2}", p.1));
            let relabelled = report
                .relabelled_share
                .iter()
                .take_while(|p| p.0 <= episode)
                .last()
                .map_or("-".into(), |p| format!("{:.1}%", 100.0 * p.1));
            println!(
                "{episode:7}  {:>30.1}%  {q:>16}  {relabelled:>10}",
                100.0 * success
            );
        }
    }
    for (primitive, points) in &report.loss {
        let last = points.last().map_or("-".into(), |p| format!("{:.4}", p.1));
        let first = points.first().map_or("-".into(), |p| format!("{:.4}", p.1));
        println!("{primitive} loss (windowed mean): first {first}, last {last}");
    }
    let shown = if all_episodes { run.episodes.len() } else { 10 };
    let rows = &run.episodes[run.episodes.len().saturating_sub(shown)..];
    if !rows.is_empty() {
        println!("episode  actor(incarnation)  goal  grasped  steps  pictures");
        for e in rows {
            print_episode(e);
        }
        if rows.len() < run.episodes.len() {
            println!(
                "(the last {} of {}; --episodes for all)",
                rows.len(),
                run.episodes.len()
            );
        }
    }
}

fn print_episode(e: &EpisodeRow) {
    println!(
        "{:7}  {:>18}  {:4}  {:>7}  {:5}  {}",
        e.number,
        format!("{}({})", e.actor, e.incarnation),
        e.goal,
        e.grasped.map_or("-".into(), |g| g.to_string()),
        e.steps,
        if e.pictures { "yes" } else { "" }
    )
}

/// The panels `--plot` draws, one series per line: a pipeline's stages follow each other,
/// each stage's episodes, actions and updates counted on from the previous stage's last.
fn charts(runs: &[Run], reports: &[RunReport], lines: &[Line]) -> Vec<plots::Chart> {
    let joined = |points: &dyn Fn(&RunReport) -> Vec<(u64, f64)>,
                  extent: &dyn Fn(&RunReport) -> u64,
                  by: f64|
     -> Vec<plots::Series> {
        lines
            .iter()
            .map(|line| {
                let mut offset = 0;
                let mut joined = Vec::new();
                for &i in &line.runs {
                    joined.extend(
                        points(&reports[i])
                            .into_iter()
                            .map(|(x, y)| ((offset + x) as f64, by * y)),
                    );
                    offset += extent(&reports[i]);
                }
                plots::Series {
                    label: line.label.clone(),
                    points: joined,
                }
            })
            .collect()
    };
    let episodes = |r: &RunReport| r.episodes;
    let updates = |r: &RunReport| r.learner_updates.unwrap_or(0);
    let q_star = runs
        .iter()
        .find_map(|r| r.config.as_ref())
        .map_or(policy::PolicyConfig::default().q_star, |c| c.policy.q_star);
    let mut primitives: Vec<&str> = reports
        .iter()
        .flat_map(|r| r.loss.iter().map(|(p, _)| p.as_str()))
        .collect();
    primitives.sort();
    primitives.dedup();
    let loss = primitives
        .into_iter()
        .flat_map(|primitive| {
            let of_primitive = move |r: &RunReport| -> Vec<(u64, f64)> {
                r.loss
                    .iter()
                    .find(|(p, _)| p == primitive)
                    .map_or_else(Vec::new, |(_, points)| points.clone())
            };
            joined(&of_primitive, &updates, 1.0)
                .into_iter()
                .filter(|s| !s.points.is_empty())
                .map(move |s| plots::Series {
                    label: format!("{} {primitive}", s.label),
                    points: s.points,
                })
        })
        .collect();
    let success = format!("Goal grasp success (last {SUCCESS_WINDOW} episodes)");
    vec![
        plots::Chart {
            title: success.clone(),
            x_label: "episodes".into(),
            y_label: "%".into(),
            series: joined(&|r| r.curve.clone(), &episodes, 100.0),
            references: Vec::new(),
            y_range: Some((0.0, 100.0)),
        },
        plots::Chart {
            title: success,
            x_label: "actions".into(),
            y_label: "%".into(),
            series: joined(&|r| r.curve_by_actions.clone(), &|r| r.actions, 100.0),
            references: Vec::new(),
            y_range: Some((0.0, 100.0)),
        },
        plots::Chart {
            title: format!("Q of goal grasps (last {SUCCESS_WINDOW} episodes)"),
            x_label: "episodes".into(),
            y_label: "predicted Q".into(),
            series: joined(&|r| r.goal_grasp_q.clone(), &episodes, 1.0),
            references: vec![(f64::from(q_star), "Q*".into())],
            y_range: None,
        },
        plots::Chart {
            title: "Relabelled share of stored transitions".into(),
            x_label: "episodes".into(),
            y_label: "%".into(),
            series: joined(&|r| r.relabelled_share.clone(), &episodes, 100.0),
            references: Vec::new(),
            y_range: Some((0.0, 100.0)),
        },
        plots::Chart {
            title: "Learner loss (windowed mean)".into(),
            x_label: "updates".into(),
            y_label: "Huber loss".into(),
            series: loss,
            references: Vec::new(),
            y_range: None,
        },
    ]
}

pub fn logs(command: LogsCommand) -> Result<()> {
    match command {
        LogsCommand::Recover { file, out } => {
            let out = out.unwrap_or_else(|| file.with_extension("recovered.mcap"));
            let summary = mcaplog::recover(&file, &out)?;
            println!(
                "{}: recovered {} messages into {}{}",
                file.display(),
                summary.messages,
                out.display(),
                if summary.damage.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", summary.damage.join("; "))
                }
            );
            Ok(())
        }
    }
}
