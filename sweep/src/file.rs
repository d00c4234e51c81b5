//! The sweep file: its TOML shape, loading and every check that can be made before any run.

use std::path::{Path, PathBuf};

use serde::Deserialize;
use toml::{Table, Value};

use crate::axis::{Axis, RawAxis};
use crate::error::SweepError;
use crate::keys;
use crate::options::SlurmOptions;

/// A loaded and checked sweep: a base config and the axes that vary it.
#[derive(Debug, Clone, PartialEq)]
pub struct Sweep {
    /// The sweep file, as given to [`Sweep::load`].
    pub path: PathBuf,
    /// The prefix of every run id: ASCII lowercase letters, digits, `-` and `_`.
    pub name: String,
    /// The base training config, resolved against the sweep file's directory.
    pub base_path: PathBuf,
    /// The base training config as read, before the budget and overrides.
    pub base: Table,
    /// Per-run length, applied to every run's config.
    pub budget: Budget,
    /// The axes in file order; their cartesian product is the set of runs.
    pub axes: Vec<Axis>,
    /// Resources for the Slurm backend.
    pub slurm: SlurmOptions,
}

/// Per-run length: sets the config's top-level `episodes` and `updates` keys.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budget {
    /// Episodes per run.
    pub episodes: Option<i64>,
    /// Learner updates per run (0: no limit).
    pub updates: Option<i64>,
}

impl Budget {
    /// The top-level keys the budget sets, with their values.
    pub(crate) fn entries(&self) -> impl Iterator<Item = (&'static str, i64)> {
        [("episodes", self.episodes), ("updates", self.updates)]
            .into_iter()
            .filter_map(|(key, value)| Some((key, value?)))
    }

    /// Sets the budget's keys in `config`.
    pub(crate) fn apply(&self, config: &mut Table) {
        for (key, value) in self.entries() {
            config.insert(key.to_string(), Value::Integer(value));
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSweep {
    name: String,
    base: PathBuf,
    #[serde(default)]
    budget: Budget,
    #[serde(default)]
    axis: Vec<RawAxis>,
    #[serde(default)]
    slurm: SlurmOptions,
}

impl Sweep {
    /// Reads and checks a sweep file and the base config it names (relative to the sweep
    /// file's directory). Every error names the sweep file, and the axis where there is one.
    pub fn load(path: &Path) -> Result<Sweep, SweepError> {
        let text = std::fs::read_to_string(path).map_err(|cause| SweepError::Read {
            path: path.to_path_buf(),
            cause,
        })?;
        let raw: RawSweep = toml::from_str(&text).map_err(|cause| SweepError::Parse {
            path: path.to_path_buf(),
            cause: Box::new(cause),
        })?;
        let invalid = |message: String| SweepError::Invalid {
            path: path.to_path_buf(),
            message,
        };

        check_name(&raw.name).map_err(invalid)?;
        check_budget(&raw.budget).map_err(invalid)?;
        raw.slurm.check().map_err(invalid)?;

        let base_path = path.parent().unwrap_or(Path::new("")).join(&raw.base);
        let base_text =
            std::fs::read_to_string(&base_path).map_err(|cause| SweepError::ReadBase {
                sweep: path.to_path_buf(),
                base: base_path.clone(),
                cause,
            })?;
        let base: Table = toml::from_str(&base_text).map_err(|cause| SweepError::ParseBase {
            sweep: path.to_path_buf(),
            base: base_path.clone(),
            cause: Box::new(cause),
        })?;

        let axes = resolve_axes(path, raw.axis, &base, &raw.budget)?;
        let sweep = Sweep {
            path: path.to_path_buf(),
            name: raw.name,
            base_path,
            base,
            budget: raw.budget,
            axes,
            slurm: raw.slurm,
        };
        sweep
            .axes
            .iter()
            .try_fold(1usize, |count, axis| count.checked_mul(axis.points.len()))
            .ok_or_else(|| invalid("the axes' product has too many runs to count".to_string()))?;
        Ok(sweep)
    }
}

fn check_name(name: &str) -> Result<(), String> {
    let allowed = |c: char| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-' || c == '_';
    if !name.is_empty() && name.chars().all(allowed) {
        Ok(())
    } else {
        Err(format!(
            "name {name:?} must be non-empty and use only a-z, 0-9, `-` and `_` \
             (it prefixes run ids and directory names)"
        ))
    }
}

fn check_budget(budget: &Budget) -> Result<(), String> {
    if budget.episodes.is_some_and(|episodes| episodes < 1) {
        return Err("budget episodes must be at least 1".to_string());
    }
    if budget.updates.is_some_and(|updates| updates < 0) {
        return Err("budget updates must not be negative (0: no limit)".to_string());
    }
    Ok(())
}

/// Resolves every axis and checks its keys: syntax, no key swept twice or nested in another,
/// none also set by the budget, and none descending into a non-table value of the base.
fn resolve_axes(
    path: &Path,
    raw_axes: Vec<RawAxis>,
    base: &Table,
    budget: &Budget,
) -> Result<Vec<Axis>, SweepError> {
    // Keys never overlap (checked below), so setting each one once here finds every path
    // error that any combination of values could meet in `expand`.
    let mut scratch = base.clone();
    budget.apply(&mut scratch);
    let mut axes: Vec<Axis> = Vec::with_capacity(raw_axes.len());
    for (index, raw) in raw_axes.into_iter().enumerate() {
        let number = index + 1;
        let error = |key: &str, message: String| SweepError::Axis {
            path: path.to_path_buf(),
            number,
            key: key.to_string(),
            message,
        };
        let described = raw.describe();
        let axis = raw
            .resolve()
            .map_err(|message| error(&described, message))?;
        for (position, key) in axis.keys.iter().enumerate() {
            let error = |message: String| error(&format!("key `{key}`"), message);
            keys::check_syntax(key).map_err(error)?;
            if let Some(earlier) = axis.keys[..position].iter().find(|k| keys::overlap(k, key)) {
                return Err(error(format!("overlaps key `{earlier}` of the same zip")));
            }
            for (earlier_index, earlier) in axes.iter().enumerate() {
                if let Some(other) = earlier.keys.iter().find(|k| keys::overlap(k, key)) {
                    let earlier_number = earlier_index + 1;
                    return Err(error(if other == key {
                        format!("is also swept by [[axis]] number {earlier_number}")
                    } else {
                        format!("overlaps key `{other}` of [[axis]] number {earlier_number}")
                    }));
                }
            }
            if let Some((budget_key, _)) = budget.entries().find(|(k, _)| k == key) {
                return Err(error(format!(
                    "`{budget_key}` is also set by `budget`; sweep it or budget it, not both"
                )));
            }
            keys::set(&mut scratch, key, axis.points[0][position].clone()).map_err(error)?;
        }
        axes.push(axis);
    }
    Ok(axes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_allow_lowercase_digits_dash_underscore() {
        assert!(check_name("stage1-lr_2").is_ok());
        assert!(check_name("").is_err());
        assert!(check_name("Stage1").is_err());
        assert!(check_name("a b").is_err());
        assert!(check_name("a/b").is_err());
    }
}
