//! `pushgrasp pretrain`: the trunks' generic visual pretraining (`learner::pretrain`) for a
//! run config's nets, written as a checkpoint a first stage starts from
//! (`pipeline --set init_from='"<dir>"'`, or `train --init-from <dir>`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use learner::checkpoint::config_hash;
use learner::{Checkpoint, Manifest, PretrainConfig, SavedNets};
use qnet::QNets;

use rundir::backend;
use rundir::config::RunConfig;

#[derive(Args)]
pub struct PretrainArgs {
    /// The run config whose nets, heightmaps and learner backend are pretrained (the first
    /// stage's: the nets of every stage have its shape).
    #[arg(long, default_value = "configs/stage1.toml")]
    config: PathBuf,
    /// The checkpoint directory to write.
    #[arg(long)]
    out: PathBuf,
    /// Random scenes drawn before training [default: 200].
    #[arg(long)]
    scenes: Option<usize>,
    /// Objects in each scene [default: 10].
    #[arg(long)]
    objects: Option<usize>,
    /// Updates, each on --batch items per net [default: 1500].
    #[arg(long)]
    steps: Option<usize>,
    /// Items per net in an update [default: 4].
    #[arg(long)]
    batch: Option<usize>,
    /// Scenes, rotations and goal masks derive from it (default: far from any run's).
    #[arg(long)]
    seed: Option<u64>,
}

pub fn pretrain(args: &PretrainArgs) -> Result<()> {
    let config = RunConfig::load(&args.config)?;
    let defaults = PretrainConfig::default();
    let settings = PretrainConfig {
        scenes: args.scenes.unwrap_or(defaults.scenes).max(1),
        objects: args.objects.unwrap_or(defaults.objects),
        steps: args.steps.unwrap_or(defaults.steps),
        batch: args.batch.unwrap_or(defaults.batch).max(1),
        seed: args.seed.unwrap_or(defaults.seed),
        ..defaults
    };
    let device = backend::open(config.backend.learner, "learner")?.device;
    device.seed(settings.seed);
    let nets = QNets::new(&config.net, &device);
    println!(
        "pretraining the trunks of {}'s nets: {} scenes of {} objects, {} updates of {} items per net",
        args.config.display(),
        settings.scenes,
        settings.objects,
        settings.steps,
        settings.batch
    );
    let started = Instant::now();
    let every = (settings.steps / 10).max(1);
    let (nets, report) =
        learner::pretrain(nets, &config.net, &config.sim, &settings, |step, loss| {
            if (step + 1) % every == 0 {
                println!(
                    "  {:6.1} s  update {}/{}  outline loss {loss:.4}",
                    started.elapsed().as_secs_f32(),
                    step + 1,
                    settings.steps
                );
            }
        })?;
    let saved = SavedNets {
        manifest: Manifest {
            stage: 0,
            updates: settings.steps as u64,
            side: config.side(),
            config_hash: config_hash(&config.net),
        },
        weights: nets.to_bytes()?,
        trained: None,
    };
    Checkpoint::at(&args.out)
        .save(&saved)
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "done in {:.1} s: outline loss {:.4} over the first updates, {:.4} over the last \
         ({:.4} for a constant map: {:.1}% of pixels are on an outline); trunks in {}, heads fresh",
        started.elapsed().as_secs_f32(),
        report.first_loss,
        report.last_loss,
        report.constant_loss,
        100.0 * report.outline_share,
        args.out.display()
    );
    Ok(())
}
