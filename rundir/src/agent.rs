//! A run's checkpoint loaded back as an agent that acts, and the arrangement files a test
//! names: what every tool that tests a checkpoint (eval, scene grasps) starts from.

use std::path::{Path, PathBuf};

use agent::Agent;
use anyhow::{Context, Result, bail};
use learner::checkpoint::config_hash;
use learner::{Checkpoint, SavedNets};
use sim::Arrangement;

use crate::backend;
use crate::config::RunConfig;
use crate::files::files_with_extension;
use crate::run_dir::RunDir;
use crate::settings::load_with;

/// A checkpoint's nets as an agent in `mode`, with the run config they were trained with
/// (`config`, else `config.toml` in the checkpoint's run directory) with `set` merged into
/// it, and their update count.
pub fn load_agent(
    checkpoint: &Path,
    config: Option<&Path>,
    set: &toml::Table,
    mode: policy::Mode,
) -> Result<(RunConfig, Agent, u64)> {
    let config_path = match config {
        Some(path) => path.to_path_buf(),
        None => checkpoint
            .parent()
            .map(|run| RunDir::new(run).config())
            .context("--checkpoint has no parent directory; name the config with --config")?,
    };
    let (config, _) = load_with(&config_path, set, "--set")?;
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
        config.side(),
        config.policy.clone(),
        mode,
        &open.device,
    );
    agent
        .load_weights(&weights)
        .with_context(|| format!("loading {}", checkpoint.display()))?;
    Ok((config, agent, manifest.updates))
}

/// The arrangements (our TOML) in `paths`, files or directories of them, each with its file
/// and its name (the file's `name`, else its stem).
pub fn named_arrangements(paths: &[PathBuf]) -> Result<Vec<(PathBuf, String, Arrangement)>> {
    arrangement_files(paths)?
        .into_iter()
        .map(|path| {
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            let arrangement = Arrangement::parse_toml(&text, &path)?;
            let name = arrangement.name.clone().unwrap_or_else(|| {
                path.file_stem().map_or_else(
                    || path.display().to_string(),
                    |s| s.to_string_lossy().into(),
                )
            });
            Ok((path, name, arrangement))
        })
        .collect()
}

/// The `.toml` files named, and those in the directories named, in order.
fn arrangement_files(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for path in paths {
        if path.is_dir() {
            files.extend(files_with_extension(path, "toml")?);
        } else {
            files.push(Path::new(path).to_path_buf());
        }
    }
    Ok(files)
}
