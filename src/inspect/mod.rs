//! `pushgrasp inspect`: what a run's MCAP logs say, without custom tools: the files and
//! processes (counts, time spans, whether one had to be recovered), the run's config, the
//! paper's metric and the learner's and buffer's curves (as tables, `--json` or a `--plot`),
//! an episode table, and one episode's pictures (`--episode K --export DIR`). Several runs at
//! once overlay their curves. `pushgrasp logs recover` rewrites a file cut short by a crash.

mod export;
mod run;

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use serde::Serialize;

use crate::run::SUCCESS_WINDOW;
use run::{EpisodeRow, FileReport, Run};

#[derive(Args)]
pub struct InspectArgs {
    /// Run directories (every .mcap in each) or .mcap files; several overlay their curves.
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
    /// Goal grasp success over the last 30 episodes, every 10 episodes.
    curve: Vec<(u64, f64)>,
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
            curve,
            goal_grasp_q: run.goal_grasp_q_curve(),
            relabelled_share: run.relabelled_curve(),
            loss: run.loss_curves(),
        }
    }
}

pub fn inspect(args: &InspectArgs) -> Result<()> {
    let runs = args
        .paths
        .iter()
        .map(|p| Run::read(p))
        .collect::<Result<Vec<_>>>()?;
    if let (Some(number), Some(dir)) = (args.episode, &args.export) {
        let [run] = runs.as_slice() else {
            bail!("--episode and --export take one run, not {}", runs.len());
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
        plots::draw(&charts(&runs, &reports), 2, path)?;
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
            "{}: {} ({} messages over {}){}",
            f.file,
            f.process.as_deref().unwrap_or("?"),
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

/// The four panels `--plot` draws, one series per run.
fn charts(runs: &[Run], reports: &[RunReport]) -> Vec<plots::Chart> {
    let series = |points: &dyn Fn(&RunReport) -> Vec<(f64, f64)>| -> Vec<plots::Series> {
        reports
            .iter()
            .map(|r| plots::Series {
                label: r.run.to_string(),
                points: points(r),
            })
            .collect()
    };
    let scaled = |points: &[(u64, f64)], by: f64| -> Vec<(f64, f64)> {
        points.iter().map(|&(x, y)| (x as f64, by * y)).collect()
    };
    let q_star = runs
        .iter()
        .find_map(|r| r.config.as_ref())
        .map_or(actor::PolicyConfig::default().q_star, |c| c.policy.q_star);
    let loss = reports
        .iter()
        .flat_map(|r| {
            r.loss.iter().map(move |(primitive, points)| plots::Series {
                label: format!("{} {primitive}", r.run),
                points: scaled(points, 1.0),
            })
        })
        .collect();
    vec![
        plots::Chart {
            title: format!("Goal grasp success (last {SUCCESS_WINDOW} episodes)"),
            x_label: "episodes".into(),
            y_label: "%".into(),
            series: series(&|r| scaled(&r.curve, 100.0)),
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
        plots::Chart {
            title: format!("Q of goal grasps (last {SUCCESS_WINDOW} episodes)"),
            x_label: "episodes".into(),
            y_label: "predicted Q".into(),
            series: series(&|r| scaled(&r.goal_grasp_q, 1.0)),
            references: vec![(f64::from(q_star), "Q*".into())],
            y_range: None,
        },
        plots::Chart {
            title: "Relabelled share of stored transitions".into(),
            x_label: "episodes".into(),
            y_label: "%".into(),
            series: series(&|r| scaled(&r.relabelled_share, 100.0)),
            references: Vec::new(),
            y_range: Some((0.0, 100.0)),
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
