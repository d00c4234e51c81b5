//! Expanding a sweep into its runs: the cartesian product of the axes, each run with its
//! overrides and its resolved config.

use toml::{Table, Value};

use crate::file::Sweep;
use crate::keys;

/// One run of a sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct RunPlan {
    /// Position in the sweep, from 0.
    pub index: usize,
    /// `<sweep name>-<index>`, the index zero-padded to as many digits as the run count has
    /// (`stage1-lr-07` of 12 runs), so ids sort in run order.
    pub id: String,
    /// The dotted keys this run sets and their values, in axis order.
    pub overrides: Vec<(String, Value)>,
    /// The base config with the budget and the overrides applied.
    pub config: Table,
}

impl Sweep {
    /// How many runs the sweep has: the product of its axes' lengths (1 with no axes).
    pub fn run_count(&self) -> usize {
        self.axes.iter().map(|axis| axis.points.len()).product()
    }

    /// Every run, the first axis varying slowest.
    pub fn expand(&self) -> Vec<RunPlan> {
        let count = self.run_count();
        let width = count.to_string().len();
        let mut base = self.base.clone();
        self.budget.apply(&mut base);
        (0..count)
            .map(|index| {
                // Mixed-radix digits of the index, the last axis the fastest.
                let mut rest = index;
                let mut picks = vec![0; self.axes.len()];
                for (pick, axis) in picks.iter_mut().zip(&self.axes).rev() {
                    *pick = rest % axis.points.len();
                    rest /= axis.points.len();
                }
                let overrides: Vec<(String, Value)> = self
                    .axes
                    .iter()
                    .zip(&picks)
                    .flat_map(|(axis, &pick)| {
                        axis.keys.iter().cloned().zip(axis.points[pick].clone())
                    })
                    .collect();
                let mut config = base.clone();
                for (key, value) in &overrides {
                    keys::set(&mut config, key, value.clone())
                        .expect("Sweep::load checked every key's path");
                }
                RunPlan {
                    index,
                    id: format!("{}-{index:0width$}", self.name),
                    overrides,
                    config,
                }
            })
            .collect()
    }
}

impl RunPlan {
    /// The overrides as `key=value` pairs, e.g. `seed=2 learning.learning_rate=0.0003`.
    pub fn label(&self) -> String {
        label(
            self.overrides
                .iter()
                .map(|(key, value)| (key.as_str(), value)),
        )
    }

    /// The resolved config as a TOML document, ready to be written as the run's config file.
    pub fn config_toml(&self) -> String {
        toml::to_string(&self.config).expect("a toml::Table always serializes")
    }
}

/// `key=value` pairs separated by spaces, values in TOML syntax.
pub(crate) fn label<'a>(pairs: impl Iterator<Item = (&'a str, &'a Value)>) -> String {
    pairs
        .map(|(key, value)| format!("{key}={value}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// One line per run: its id, then its overrides.
pub fn dry_run_listing(runs: &[RunPlan]) -> String {
    let mut listing = String::new();
    for run in runs {
        let label = run.label();
        let line = if label.is_empty() {
            run.id.clone()
        } else {
            format!("{}  {label}", run.id)
        };
        listing.push_str(&line);
        listing.push('\n');
    }
    listing
}
