//! A sweep file's runs, each resolved config checked the way `pushgrasp train` will read it
//! (`RunConfig`: unknown keys refused, then `validate`), before anything starts.

use std::path::Path;

use crate::{Axis, RunPlan, Sweep, dry_run_listing};
use anyhow::{Context, Result, anyhow};

use rundir::config::RunConfig;

/// A loaded sweep and its runs, every one with a valid config.
pub struct Plan {
    pub sweep: Sweep,
    pub runs: Vec<(RunPlan, RunConfig)>,
}

impl Plan {
    /// Loads the sweep file and checks every run's config; an error names the run and, where
    /// one override alone breaks the base config, that key.
    pub fn load(path: &Path) -> Result<Plan> {
        let sweep = Sweep::load(path)?;
        // The base config with the budget, before any override: if it is not a valid
        // config itself, no run's error says anything about the run.
        parse(&with_overrides(&sweep, &[])).map_err(|e| {
            anyhow!(
                "{}: the base config {} (with the sweep's budget) is not a valid training \
                 config: {e}",
                sweep.path.display(),
                sweep.base_path.display()
            )
        })?;
        let runs = sweep
            .expand()
            .into_iter()
            .map(|run| {
                let config = check(&sweep, &run)
                    .with_context(|| format!("{}: run {}", sweep.path.display(), run.id))?;
                Ok((run, config))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Plan { sweep, runs })
    }

    /// The dry run: the runs with their overrides, with `verbose` their resolved configs.
    pub fn print(&self, verbose: bool) {
        let sweep = &self.sweep;
        println!(
            "sweep {}: {} runs over {}",
            sweep.name,
            self.runs.len(),
            sweep.base_path.display()
        );
        let runs: Vec<RunPlan> = self.runs.iter().map(|(run, _)| run.clone()).collect();
        print!("{}", dry_run_listing(&runs));
        if verbose {
            for run in &runs {
                println!("\n# {}\n{}", run.id, run.config_toml());
            }
        }
        println!("every run's config is valid");
    }

    /// The most actors any run has.
    pub fn max_actors(&self) -> u32 {
        self.runs
            .iter()
            .map(|(_, config)| config.actors)
            .max()
            .unwrap_or(1)
    }
}

/// A run's config as `pushgrasp train` reads it from the file the sweep writes.
fn parse(toml_text: &str) -> Result<RunConfig> {
    // `message()` rather than the whole error: its line excerpt would point into a file the
    // user never wrote.
    let config: RunConfig = toml::from_str(toml_text).map_err(|e| anyhow!("{}", e.message()))?;
    config.validate()?;
    Ok(config)
}

/// The base config with the budget and only `overrides` applied, as TOML.
fn with_overrides(sweep: &Sweep, overrides: &[(String, toml::Value)]) -> String {
    let single = Sweep {
        axes: overrides
            .iter()
            .map(|(key, value)| Axis {
                keys: vec![key.clone()],
                points: vec![vec![value.clone()]],
            })
            .collect(),
        ..sweep.clone()
    };
    single.expand()[0].config_toml()
}

/// Checks one run; on an error, finds the override that breaks the base config by itself.
fn check(sweep: &Sweep, run: &RunPlan) -> Result<RunConfig> {
    parse(&run.config_toml()).map_err(|error| {
        let culprit = run.overrides.iter().find_map(|(key, value)| {
            let alone = with_overrides(sweep, &[(key.clone(), value.clone())]);
            parse(&alone)
                .err()
                .map(|e| format!("key `{key}` = {value}: {e}"))
        });
        match culprit {
            Some(message) => anyhow!(message),
            // Only the combination fails (or a check across keys): name all of them.
            None => anyhow!("with {}: {error}", run.label()),
        }
    })
}
