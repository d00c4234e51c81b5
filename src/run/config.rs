//! A training run's config (`configs/stage<N>.toml`): what every role of the run reads, every
//! hyper-parameter visible.

use std::path::Path;

use anyhow::{Context, Result, bail};
use buffer::BufferConfig;
use learner::{LearningConfig, TrainedNet};
use qnet::QNetConfig;
use serde::{Deserialize, Serialize};
use sim::SimConfig;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// 1: goal-conditioned grasping; 2: pushing, the grasp net frozen; 3: both alternately.
    pub stage: u8,
    /// Every seed of the run (scenes, exploration, initial weights) derives from this one.
    pub seed: u64,
    /// Objects dropped per scene.
    pub objects: usize,
    /// A scene is dropped again once it is empty or after this many failed grasps in a row.
    pub max_failures_per_scene: usize,
    /// Actor processes when `--actors` is not given.
    pub actors: u32,
    /// The run ends once this many episodes have ended (counted by the buffer).
    pub episodes: u64,
    /// ... or once the learner has taken this many updates (0: no limit).
    #[serde(default)]
    pub updates: u64,
    #[serde(default)]
    pub sim: SimConfig,
    #[serde(default)]
    pub policy: actor::PolicyConfig,
    #[serde(default)]
    pub net: QNetConfig,
    #[serde(default)]
    pub learning: LearningConfig,
    #[serde(default)]
    pub buffer: BufferConfig,
    #[serde(default)]
    pub learner: LearnerSchedule,
}

/// How the learner paces itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearnerSchedule {
    /// Transitions per update.
    pub batch_size: u32,
    /// Updates between weight broadcasts to the actors.
    pub publish_every: u64,
    /// Updates between checkpoints (one is also written at shutdown).
    pub checkpoint_every: u64,
}

impl Default for LearnerSchedule {
    fn default() -> Self {
        Self {
            batch_size: 4,
            publish_every: 1,
            checkpoint_every: 500,
        }
    }
}

impl RunConfig {
    pub fn load(path: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let config: Self =
            toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        config
            .validate()
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(config)
    }

    /// Checks what serde cannot: ranges and the parts' own rules.
    pub fn validate(&self) -> Result<()> {
        if !(1..=3).contains(&self.stage) {
            bail!("stage: {} is not 1, 2 or 3", self.stage);
        }
        if self.objects == 0 {
            bail!("objects: must be at least 1");
        }
        if self.actors == 0 {
            bail!("actors: must be at least 1");
        }
        if self.episodes == 0 && self.updates == 0 {
            bail!("episodes, updates: at least one budget must be above 0");
        }
        if self.learner.batch_size == 0 || self.learner.publish_every == 0 {
            bail!("learner: batch_size and publish_every must be at least 1");
        }
        if self.learner.checkpoint_every == 0 {
            bail!("learner.checkpoint_every: must be at least 1");
        }
        self.buffer
            .validate()
            .map_err(|e| anyhow::anyhow!("buffer.{e}"))?;
        self.sim.grid().map_err(|e| anyhow::anyhow!("sim: {e}"))?;
        Ok(())
    }

    /// The policy's mode in this stage.
    pub fn mode(&self) -> actor::Mode {
        if self.stage == 1 {
            actor::Mode::GraspOnly
        } else {
            actor::Mode::PushGrasp
        }
    }

    /// The nets the learner trains in this stage, in the order its updates alternate.
    pub fn trained_nets(&self) -> &'static [TrainedNet] {
        match self.stage {
            1 => &[TrainedNet::Grasp],
            2 => &[TrainedNet::Push],
            _ => &[TrainedNet::Grasp, TrainedNet::Push],
        }
    }

    /// Heightmap side in pixels.
    pub fn side(&self) -> usize {
        self.sim.grid().expect("validated").side()
    }
}
