//! The Slurm backend: the sweep's runs still to do as one job array (`sweep.sbatch`, written
//! by the `sweep` crate), submitted with `sbatch --parsable`, the job recorded in
//! `sweep.json`; and the array tasks' states, from `sacct` and `squeue`, for `sweep status`.

use std::collections::BTreeMap;
use std::ffi::OsStr;
use std::process::Command;

use crate::{JobState, RunPlan, bash_quote, job_array_script, parse_sacct, parse_squeue};
use anyhow::{Context, Result, anyhow, bail};

use super::dir::{SlurmJob, SweepDir, SweepState};
use super::plan::Plan;

/// What each array task runs; `{exe}` is this program, `{sweep_dir}` and `{run_id}` are
/// filled in by `job_array_script`. A task whose run directory already holds a config
/// continues it: the sweep was resumed, or Slurm requeued the task.
const TASK: &str = r#"RUN_DIR={sweep_dir}/{run_id}
RESUME=
if [ -e "$RUN_DIR/config.toml" ]; then RESUME=--resume; fi
exec {exe} train --config {sweep_dir}/runs/{run_id}.toml --logs {sweep_dir} --run-id {run_id} $RESUME"#;

/// Writes the job script for every run not finished yet and, unless `no_submit`, submits it.
pub fn submit(
    dir: &SweepDir,
    mut state: SweepState,
    plan: &Plan,
    max_parallel: Option<u32>,
    no_submit: bool,
) -> Result<()> {
    let mut runs: Vec<RunPlan> = Vec::new();
    for (run, _) in &plan.runs {
        if !dir.finished(&run.id)? {
            runs.push(run.clone());
        }
    }
    if runs.is_empty() {
        println!("every run of sweep {} has finished", state.name);
        return Ok(());
    }
    // Tasks start in whatever directory sbatch ran in, on whichever node: absolute paths.
    let sweep_dir = std::path::absolute(dir.path())
        .with_context(|| format!("resolving {}", dir.path().display()))?;
    std::fs::create_dir_all(sweep_dir.join("slurm"))?;
    let exe = std::env::current_exe().context("finding this program")?;
    let exe = exe
        .to_str()
        .ok_or_else(|| anyhow!("this program's path {} is not UTF-8", exe.display()))?;
    let mut sweep = plan.sweep.clone();
    if max_parallel.is_some() {
        sweep.slurm.max_parallel = max_parallel;
    }
    let command = TASK.replace("{exe}", &bash_quote(exe));
    let script = job_array_script(&sweep, &runs, &sweep_dir, &command)?;
    let path = dir.script();
    std::fs::write(&path, script).with_context(|| format!("writing {}", path.display()))?;
    if no_submit {
        println!(
            "wrote {} ({} array tasks); submit it with `{} --backend slurm` (which records \
             the job for `pushgrasp sweep status`), or with `sbatch {}`",
            path.display(),
            runs.len(),
            dir.resume_command(&state),
            path.display()
        );
        return Ok(());
    }
    let job_id = sbatch(&path).map_err(|e| {
        anyhow!("{e:#}; --no-submit writes the script only, --backend local runs the sweep here")
    })?;
    // A failure of an earlier local start no longer describes a run that runs again.
    for entry in &mut state.runs {
        if runs.iter().any(|run| run.id == entry.id) {
            entry.failure = None;
        }
    }
    state.slurm = Some(SlurmJob {
        job_id: job_id.clone(),
        runs: runs.iter().map(|run| run.id.clone()).collect(),
    });
    dir.write_state(&state)?;
    println!(
        "submitted job array {job_id}: {} tasks, their output in {}; follow it with \
         `pushgrasp sweep status {}`",
        runs.len(),
        sweep_dir.join("slurm").display(),
        dir.path().display()
    );
    Ok(())
}

/// Refuses to go on while the sweep's last job array still has tasks in the queue (a run
/// started twice would fight over its directory). Without `squeue` there is nothing to ask.
pub fn ensure_idle(state: &SweepState) -> Result<()> {
    let Some(job) = &state.slurm else {
        return Ok(());
    };
    let Ok(queued) = queue(job) else {
        return Ok(());
    };
    if !queued.is_empty() {
        bail!(
            "job array {} of this sweep still has {} tasks queued or running; wait for them \
             or `scancel {}` first",
            job.job_id,
            queued.len(),
            job.job_id
        );
    }
    Ok(())
}

/// Each run's array task state, as text, from `sacct` where Slurm keeps accounts and from
/// `squeue` for the tasks still queued; and a note for each tool that could not answer.
pub fn task_states(job: &SlurmJob) -> (BTreeMap<String, String>, Vec<String>) {
    let mut notes = Vec::new();
    let mut by_index = BTreeMap::new();
    let sacct = query(
        "sacct",
        [
            "-j",
            &job.job_id,
            "--parsable2",
            "--noheader",
            "--format=JobID,State",
        ],
    )
    .and_then(|text| parse_sacct(&text).map_err(|e| format!("sacct: {e}")));
    match sacct {
        Ok(states) => by_index.extend(states),
        Err(why) => notes.push(why),
    }
    let accounted = notes.is_empty();
    let queued = match queue(job) {
        Ok(states) => Some(states),
        Err(why) => {
            notes.push(why);
            None
        }
    };
    let states = job
        .runs
        .iter()
        .enumerate()
        .filter_map(|(index, id)| {
            let state = queued
                .as_ref()
                .and_then(|queue| queue.get(&index))
                .or_else(|| by_index.get(&index));
            let text = match (state, &queued) {
                (Some(state), _) => describe(state),
                // Not in the queue and no accounts to say how it ended.
                (None, Some(_)) if !accounted => "left the queue".to_string(),
                _ => return None,
            };
            Some((id.clone(), text))
        })
        .collect();
    (states, notes)
}

/// The array's tasks still in the queue, by array index.
fn queue(job: &SlurmJob) -> Result<BTreeMap<usize, JobState>, String> {
    let args = ["-j", &job.job_id, "--array", "--noheader", "--format=%i|%T"];
    match query("squeue", args) {
        Ok(text) => parse_squeue(&text).map_err(|e| format!("squeue: {e}")),
        // Slurm forgets a job some minutes after its last task ended.
        Err(why) if why.contains("Invalid job id") => Ok(BTreeMap::new()),
        Err(why) => Err(why),
    }
}

fn describe(state: &JobState) -> String {
    match state {
        JobState::Pending => "pending".into(),
        JobState::Running => "running".into(),
        JobState::Completed => "completed".into(),
        JobState::Failed => "failed".into(),
        JobState::Cancelled => "cancelled".into(),
        JobState::Other(state) => state.to_lowercase(),
    }
}

/// Submits the batch script at `path`; its job id.
pub(crate) fn sbatch(path: &std::path::Path) -> Result<String> {
    let output = query("sbatch", [OsStr::new("--parsable"), path.as_os_str()])
        .map_err(|why| anyhow!("cannot submit {}: {why}", path.display()))?;
    // `--parsable` prints `<job id>` or `<job id>;<cluster>`.
    let job_id = output.trim().split(';').next().unwrap_or("").to_string();
    if job_id.is_empty() || !job_id.bytes().all(|b| b.is_ascii_digit()) {
        bail!("sbatch --parsable printed {output:?}, not a job id");
    }
    Ok(job_id)
}

/// Runs a Slurm command; its stdout, or why not.
fn query<S: AsRef<OsStr>>(
    program: &str,
    args: impl IntoIterator<Item = S>,
) -> Result<String, String> {
    match Command::new(program).args(args).output() {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Err(format!("{program} is not on PATH (no Slurm client here)"))
        }
        Err(e) => Err(format!("cannot run {program}: {e}")),
        Ok(output) if !output.status.success() => Err(format!(
            "{program} failed ({}): {}",
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        )),
        Ok(output) => Ok(String::from_utf8_lossy(&output.stdout).into_owned()),
    }
}
