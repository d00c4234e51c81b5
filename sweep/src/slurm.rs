//! The Slurm backend's job-array script: one array task per run.

use std::path::Path;

use crate::error::SweepError;
use crate::expand::RunPlan;
use crate::file::Sweep;

/// Renders the bash script `sbatch` takes to run `runs` as a job array.
///
/// Each array task runs `command` with `{run_id}` replaced by `"$RUN_ID"` (its run's id) and
/// `{sweep_dir}` by `sweep_dir` quoted for bash. Task output goes to
/// `<sweep_dir>/slurm/%A_%a.out`; Slurm does not create that directory, the caller must.
/// `sweep_dir` should be absolute: tasks start in the directory `sbatch` was run from.
pub fn job_array_script(
    sweep: &Sweep,
    runs: &[RunPlan],
    sweep_dir: &Path,
    command: &str,
) -> Result<String, SweepError> {
    let fail = |message: String| SweepError::Script(message);
    if runs.is_empty() {
        return Err(fail("no runs to submit".to_string()));
    }
    let dir = sweep_dir
        .to_str()
        .ok_or_else(|| fail(format!("sweep directory {sweep_dir:?} is not UTF-8")))?;
    // No #SBATCH line can hold a line break, and a backslash in --output turns off
    // Slurm's `%A`/`%a` substitution.
    if dir.contains(['\n', '\r', '\\']) {
        return Err(fail(format!(
            "sweep directory {dir:?} contains a line break or a backslash, which its \
             #SBATCH --output line cannot hold"
        )));
    }
    let slurm = &sweep.slurm;
    let cpus = match slurm.cpus_per_task {
        Some(cpus) => i64::from(cpus),
        None => default_cpus(runs)?,
    };

    let mut array = format!("0-{}", runs.len() - 1);
    if let Some(max) = slurm.max_parallel {
        array.push_str(&format!("%{max}"));
    }
    let mut options = vec![
        format!("--job-name={}", sweep.name),
        format!("--array={array}"),
    ];
    for (name, value) in [
        ("partition", &slurm.partition),
        ("time", &slurm.time),
        ("mem", &slurm.mem),
    ] {
        if let Some(value) = value {
            options.push(format!("--{name}={value}"));
        }
    }
    options.push(format!("--cpus-per-task={cpus}"));
    // `%` starts a filename pattern in --output, so one in the directory is doubled.
    let output = format!("{}/slurm/%A_%a.out", dir.replace('%', "%%"));
    options.push(format!("--output={}", sbatch_quote(&output)));
    options.extend(slurm.extra.iter().cloned());

    let mut script = String::from("#!/bin/bash\n");
    for option in &options {
        script.push_str(&format!("#SBATCH {option}\n"));
    }
    script.push_str(&format!(
        "# Sweep {}: {} runs, one per array task.\n",
        sweep.name,
        runs.len()
    ));
    script.push_str("set -euo pipefail\n\nRUNS=(\n");
    for run in runs {
        script.push_str(&format!("  {}\n", bash_quote(&run.id)));
    }
    script.push_str(")\nRUN_ID=${RUNS[$SLURM_ARRAY_TASK_ID]}\n\n");
    let command = command
        .replace("{run_id}", "\"$RUN_ID\"")
        .replace("{sweep_dir}", &bash_quote(dir));
    script.push_str(&command);
    script.push('\n');
    Ok(script)
}

/// The largest `actors` + 2 over the runs' configs.
fn default_cpus(runs: &[RunPlan]) -> Result<i64, SweepError> {
    runs.iter()
        .map(|run| {
            run.config
                .get("actors")
                .and_then(toml::Value::as_integer)
                .map(|actors| actors.saturating_add(2))
                .ok_or_else(|| {
                    SweepError::Script(format!(
                        "run {} has no integer `actors` to size --cpus-per-task from; \
                         set [slurm] cpus_per_task",
                        run.id
                    ))
                })
        })
        .try_fold(1, |most, cpus| Ok(most.max(cpus?)))
}

/// `text` as one bash word: single-quoted, each embedded `'` written as `'\''`.
pub fn bash_quote(text: &str) -> String {
    format!("'{}'", text.replace('\'', r"'\''"))
}

/// `text` as one argument of an `#SBATCH` line. sbatch reads these lines itself, not bash:
/// double quotes keep spaces together, and a backslash makes the next character literal,
/// which older releases need even inside quotes for `#` (else a comment starts there).
fn sbatch_quote(text: &str) -> String {
    let mut quoted = String::from("\"");
    for c in text.chars() {
        if matches!(c, '\\' | '"' | '\'' | '#') {
            quoted.push('\\');
        }
        quoted.push(c);
    }
    quoted.push('"');
    quoted
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bash_quote_escapes_single_quotes() {
        assert_eq!(bash_quote("plain"), "'plain'");
        assert_eq!(bash_quote("it's here"), r"'it'\''s here'");
    }

    #[test]
    fn sbatch_quote_escapes_what_sbatch_reads() {
        assert_eq!(sbatch_quote("a b"), "\"a b\"");
        assert_eq!(sbatch_quote(r##"it's "#1\"##), r##""it\'s \"\#1\\""##);
    }
}
