//! `pushgrasp sweep status <sweep-dir>`: where each run of a sweep stands, read from its
//! directory, with its episodes so far; for a sweep submitted to Slurm, also the state of
//! each run's array task.

use std::collections::BTreeMap;

use anyhow::Result;

use super::dir::{RunState, SweepDir};
use super::{submit, table};

pub fn print(dir: &SweepDir) -> Result<()> {
    let state = dir.read_state()?;
    let plans = dir.plans(&state)?;
    let tasks = state.slurm.as_ref().map(submit::task_states);

    let mut header = vec!["run".to_string(), "state".into(), "episodes".into()];
    if tasks.is_some() {
        header.push("slurm task".into());
    }
    let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
    let mut rows = Vec::new();
    for (entry, plan) in state.runs.iter().zip(&plans) {
        let run_state = dir.run_state(entry)?;
        let episodes = match &run_state {
            RunState::Running => dir.live_episodes(&entry.id),
            _ => dir.summary(&entry.id)?.map(|s| s.buffer.episodes),
        };
        let budget = plan
            .config
            .get("episodes")
            .map_or("?".to_string(), ToString::to_string);
        let mut row = vec![
            entry.id.clone(),
            run_state.to_string(),
            format!(
                "{}/{budget}",
                episodes.map_or("-".to_string(), |n| n.to_string())
            ),
        ];
        if let Some((states, _)) = &tasks {
            row.push(states.get(&entry.id).cloned().unwrap_or("-".into()));
        }
        *counts.entry(run_state.kind()).or_default() += 1;
        rows.push(row);
    }

    let counts: Vec<String> = counts
        .iter()
        .map(|(kind, n)| format!("{n} {kind}"))
        .collect();
    println!(
        "sweep {} ({} backend{}): {} runs, {}",
        state.name,
        state.backend,
        state
            .slurm
            .as_ref()
            .map_or(String::new(), |job| format!(", job array {}", job.job_id)),
        state.runs.len(),
        counts.join(", ")
    );
    print!("{}", table::render(&header, &rows));
    for note in tasks.iter().flat_map(|(_, notes)| notes) {
        println!("({note})");
    }
    Ok(())
}
