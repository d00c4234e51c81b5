//! The `[slurm]` section of a sweep file: what each array task asks Slurm for.

use serde::Deserialize;

/// The `[slurm]` section of a sweep file; every field is optional.
#[derive(Debug, Clone, Default, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SlurmOptions {
    /// `--partition`.
    pub partition: Option<String>,
    /// `--time`, e.g. `"02:00:00"`.
    pub time: Option<String>,
    /// `--mem`, e.g. `"8G"`.
    pub mem: Option<String>,
    /// `--cpus-per-task`; by default the largest `actors` + 2 over the runs (the actors, the
    /// learner and the buffer).
    pub cpus_per_task: Option<u32>,
    /// At most this many array tasks at once (`--array=...%N`).
    pub max_parallel: Option<u32>,
    /// More `#SBATCH` options, one per string, without the `#SBATCH` prefix,
    /// e.g. `"--gres=gpu:1"`.
    #[serde(default)]
    pub extra: Vec<String>,
}

impl SlurmOptions {
    /// Checks that every option fits on its `#SBATCH` line.
    pub(crate) fn check(&self) -> Result<(), String> {
        // sbatch splits these lines on whitespace and treats quotes, `\` and `#` specially.
        for (name, value) in [
            ("partition", &self.partition),
            ("time", &self.time),
            ("mem", &self.mem),
        ] {
            if let Some(value) = value
                && (value.is_empty()
                    || value
                        .chars()
                        .any(|c| c.is_whitespace() || matches!(c, '"' | '\'' | '\\' | '#')))
            {
                return Err(format!(
                    "[slurm] {name} = {value:?} must be non-empty, without spaces, quotes, \
                     `\\` or `#`"
                ));
            }
        }
        if self.cpus_per_task == Some(0) {
            return Err("[slurm] cpus_per_task must be at least 1".to_string());
        }
        if self.max_parallel == Some(0) {
            return Err("[slurm] max_parallel must be at least 1".to_string());
        }
        for line in &self.extra {
            if line.trim().is_empty() || line.contains(['\n', '\r']) || line.starts_with('#') {
                return Err(format!(
                    "[slurm] extra line {line:?} must be one non-empty line of options, \
                     without the `#SBATCH` prefix"
                ));
            }
        }
        Ok(())
    }
}
