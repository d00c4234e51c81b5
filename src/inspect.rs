//! `pushgrasp inspect`: what a run's MCAP logs say, without custom tools: the files (counts,
//! whether one had to be recovered), the paper's metric over the run, and the counts the
//! processes kept. `pushgrasp logs recover` rewrites a file cut short by a crash.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use serde::Serialize;
use serde_json::Value;

use crate::run::SUCCESS_WINDOW;
use crate::run::record::{ACTOR_STEP, BUFFER_EPISODE, BUFFER_STATS, LEARNER_UPDATE};

#[derive(Args)]
pub struct InspectArgs {
    /// A run directory (every .mcap in it) or one .mcap file.
    path: PathBuf,
    /// Print one JSON object instead of tables.
    #[arg(long)]
    json: bool,
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

#[derive(Serialize)]
struct FileReport {
    file: String,
    messages: u64,
    recovered: bool,
    damage: Vec<String>,
    channels: Vec<(String, u64)>,
}

/// The figures `--json` prints.
#[derive(Serialize)]
struct RunReport {
    files: Vec<FileReport>,
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
}

fn mcap_files(path: &Path) -> Result<Vec<PathBuf>> {
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .with_context(|| format!("reading {}", path.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("{}: no .mcap files", path.display());
    }
    Ok(files)
}

fn count(value: &Value, field: &str) -> Option<u64> {
    value.get(field).and_then(Value::as_u64)
}

pub fn inspect(args: &InspectArgs) -> Result<()> {
    let mut report = RunReport {
        files: Vec::new(),
        episodes: 0,
        grasp_attempts: 0,
        goal_grasp_success_last30: None,
        steps_sent: 0,
        steps_received: None,
        learner_updates: None,
        curve: Vec::new(),
    };
    let mut outcomes = Vec::new();
    for file in mcap_files(&args.path)? {
        let summary = mcaplog::read_summary(&file)?;
        // Each topic read is a pass over the file: only where the topic has messages.
        let messages = |topic: &str| -> Result<Vec<Value>> {
            if summary.messages_on(topic) == 0 {
                return Ok(Vec::new());
            }
            Ok(mcaplog::json_messages(&file, topic)?)
        };
        report.steps_sent += summary.messages_on(ACTOR_STEP);
        report.grasp_attempts += messages(ACTOR_STEP)?
            .iter()
            .filter(|s| s["primitive"] == "grasp")
            .count() as u64;
        for end in messages(BUFFER_EPISODE)? {
            outcomes.push(end["grasped"] == end["goal"]);
        }
        if let Some(last) = messages(BUFFER_STATS)?.last() {
            report.steps_received = count(last, "steps_received");
        }
        if let Some(last) = messages(LEARNER_UPDATE)?.last() {
            report.learner_updates = count(last, "updates");
        }
        report.files.push(FileReport {
            file: file.display().to_string(),
            messages: summary.messages,
            recovered: summary.recovered,
            damage: summary.damage.clone(),
            channels: summary
                .channels
                .iter()
                .map(|c| (c.topic.clone(), c.messages))
                .collect(),
        });
    }
    let success =
        |window: &[bool]| window.iter().filter(|&&g| g).count() as f64 / window.len() as f64;
    report.episodes = outcomes.len() as u64;
    if !outcomes.is_empty() {
        let n = outcomes.len();
        report.goal_grasp_success_last30 =
            Some(success(&outcomes[n.saturating_sub(SUCCESS_WINDOW)..]));
        report.curve = (1..=n)
            .filter(|i| i % 10 == 0 || *i == n)
            .map(|i| {
                (
                    i as u64,
                    success(&outcomes[i.saturating_sub(SUCCESS_WINDOW)..i]),
                )
            })
            .collect();
    }

    if args.json {
        println!("{}", serde_json::to_string(&report)?);
        return Ok(());
    }
    for f in &report.files {
        println!(
            "{}: {} messages{}",
            f.file,
            f.messages,
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
        println!("episode  goal grasp success (last {SUCCESS_WINDOW})");
        for (episode, s) in &report.curve {
            println!("{episode:7}  {:5.1}%", 100.0 * s);
        }
    }
    Ok(())
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
