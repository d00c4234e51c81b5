//! A run's checkpoint loaded back as an agent that acts: what every tool that tests a
//! checkpoint (eval, scene grasps) starts from.

use std::path::Path;

use agent::Agent;
use anyhow::{Context, Result, bail};
use learner::checkpoint::config_hash;
use learner::{Checkpoint, SavedNets};

use crate::backend;
use crate::config::RunConfig;
use crate::run_dir::RunDir;
use crate::settings::load_with;

/// A checkpoint's nets as an agent in `mode`, with the run config they were trained with
/// (`config`, else `config.toml` in the checkpoint's run directory) with `set` merged into
/// it (`by`: what gave the settings, for their errors), and their update count.
pub fn load_agent(
    checkpoint: &Path,
    config: Option<&Path>,
    set: &toml::Table,
    by: &str,
    mode: policy::Mode,
) -> Result<(RunConfig, Agent, u64)> {
    let config_path = match config {
        Some(path) => path.to_path_buf(),
        None => checkpoint
            .parent()
            .map(|run| RunDir::new(run).config())
            .context("--checkpoint has no parent directory; name the config with --config")?,
    };
    let (config, _) = load_with(&config_path, set, by)?;
    let SavedNets {
        manifest, weights, ..
    } = Checkpoint::at(checkpoint)
        .load(&config_hash(&config.net))
        .with_context(|| format!("the nets of {}", config_path.display()))?;
    if manifest.side != config.side() {
        bail!(
            "{}: trained at {} px, but {} gives {} px",
            checkpoint.display(),
            manifest.side,
            config_path.display(),
            config.side()
        );
    }
    let open = backend::open(config.backend.actors, "actors")?;
    if let Some(adapter) = &open.adapter {
        eprintln!("the nets on {}: {adapter}", config.backend.actors);
    }
    let mut agent = Agent::new(
        &config.net,
        &config.sim,
        config.policy.clone(),
        mode,
        &open.device,
    );
    agent
        .load_weights(&weights)
        .with_context(|| format!("loading {}", checkpoint.display()))?;
    Ok((config, agent, manifest.updates))
}
