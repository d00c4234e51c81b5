//! A training run's config (`configs/stage<N>.toml`): what every role of the run reads, every
//! hyper-parameter visible.

use std::path::Path;

use anyhow::{Context, Result, bail};
use buffer::BufferConfig;
use learner::{LearningConfig, TrainedNet};
use qnet::QNetConfig;
use rand::RngExt;
use serde::{Deserialize, Serialize};
use sim::{Rows, SimConfig};

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
    /// Scenes that start with a touching row of objects.
    #[serde(default)]
    pub rows: RowScenes,
    /// Before each grasp it executes, an actor tries this many other grasps of the goal
    /// (pixels and angles drawn as exploration draws them) on exact copies of the scene and
    /// ships each as an experience of its own: denser grasp labels per scene, which only a
    /// simulator can give. 0: the paper's one grasp per episode.
    #[serde(default)]
    pub grasp_trials: usize,
    /// Actor processes when `--actors` is not given.
    pub actors: u32,
    /// The run ends once this many episodes have ended (counted by the buffer).
    pub episodes: u64,
    /// ... or once the learner has taken this many updates (0: no limit).
    #[serde(default)]
    pub updates: u64,
    /// The checkpoint (of an earlier stage) whose weights both nets start from; a resumed
    /// run starts from its own checkpoint instead. Set by `--init-from` and the pipeline.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_from: Option<std::path::PathBuf>,
    #[serde(default)]
    pub sim: SimConfig,
    #[serde(default)]
    pub policy: policy::PolicyConfig,
    /// What a push earns: "dense" (the paper's, judged by the grasp net), "change" (VPG's)
    /// or "none" (the ablation without a push reward).
    #[serde(default)]
    pub push_reward: policy::PushReward,
    /// Ape-X exploration instead of the policy's decaying schedule: actor i of N explores
    /// with a fixed epsilon^(1 + alpha i / (N - 1)).
    #[serde(default)]
    pub apex_epsilon: Option<ApexEpsilon>,
    #[serde(default)]
    pub net: QNetConfig,
    #[serde(default)]
    pub learning: LearningConfig,
    #[serde(default)]
    pub buffer: BufferConfig,
    #[serde(default)]
    pub learner: LearnerSchedule,
    #[serde(default)]
    pub logging: LoggingConfig,
}

/// What the roles write to their MCAP logs beyond every step, episode and update.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoggingConfig {
    /// False: no role writes an MCAP log (reports and `summary.json` are still written).
    pub enabled: bool,
    /// An actor logs what it saw (colour, height, grasp and push Q, the scene) at every step
    /// of every this many episodes (0: never).
    pub image_every: u64,
}

impl Default for LoggingConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            image_every: 10,
        }
    }
}

/// Training scenes whose first objects lie side by side in a touching row (or in `lines`
/// rows side by side, a packed cluster) before the others drop: the pattern of the paper's
/// challenging arrangements, where neighbours spoil many of the goal's grasps, which random
/// drops rarely make. Evaluation's random scenes never have one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RowScenes {
    /// Share of new scenes that start with a row (0: the paper's random drops alone).
    pub share: f64,
    /// Objects in the row (at most the scene's).
    pub objects: usize,
    /// Lines the row's objects are laid in, side by side (more than one: a packed cluster).
    pub lines: usize,
}

impl Default for RowScenes {
    fn default() -> Self {
        Self {
            share: 0.0,
            objects: 3,
            lines: 1,
        }
    }
}

impl RowScenes {
    /// The next scene's rows: `objects` in `lines` with probability `share`, else none (no
    /// draw at all when `share` is 0, so such runs see the scenes they always saw).
    pub fn draw(&self, rng: &mut impl rand::Rng) -> Rows {
        if self.share > 0.0 && rng.random_bool(self.share) {
            Rows {
                blocks: self.objects,
                lines: self.lines,
            }
        } else {
            Rows::NONE
        }
    }
}

/// Ape-X's per-actor exploration rates (Horgan et al. 2018 use epsilon 0.4, alpha 7).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ApexEpsilon {
    pub epsilon: f64,
    pub alpha: f64,
}

impl ApexEpsilon {
    /// The fixed exploration rate of actor `index` of `actors`.
    pub fn for_actor(&self, index: u32, actors: u32) -> f32 {
        let spread = if actors > 1 {
            f64::from(index) / f64::from(actors - 1)
        } else {
            0.0
        };
        self.epsilon.powf(1.0 + self.alpha * spread) as f32
    }
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
        Self::parse(&text, &path.display().to_string())
    }

    /// Reads and checks a config's text; errors name `origin`.
    pub fn parse(text: &str, origin: &str) -> Result<Self> {
        let config: Self = toml::from_str(text).map_err(|e| anyhow::anyhow!("{origin}: {e}"))?;
        config
            .validate()
            .map_err(|e| anyhow::anyhow!("{origin}: {e}"))?;
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
        if !(0.0..=1.0).contains(&self.rows.share) {
            bail!("rows.share: {} is not in [0, 1]", self.rows.share);
        }
        if self.rows.share > 0.0 && !(2..=self.objects).contains(&self.rows.objects) {
            bail!(
                "rows.objects: {} is not between 2 and the scene's {} objects",
                self.rows.objects,
                self.objects
            );
        }
        if !(1..=self.rows.objects.max(1)).contains(&self.rows.lines) {
            bail!(
                "rows.lines: {} is not between 1 and the row's {} objects",
                self.rows.lines,
                self.rows.objects
            );
        }
        if self.grasp_trials > 0 && !self.trained_nets().contains(&TrainedNet::Grasp) {
            bail!(
                "grasp_trials: stage {} does not train the grasp net; its trials would teach nothing",
                self.stage
            );
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
        self.sim.validate().map_err(|e| e.in_table("sim"))?;
        self.policy.validate().map_err(|e| e.in_table("policy"))?;
        self.net.validate().map_err(|e| e.in_table("net"))?;
        self.learning
            .validate()
            .map_err(|e| e.in_table("learning"))?;
        self.buffer.validate().map_err(|e| e.in_table("buffer"))?;
        if let Some(apex) = &self.apex_epsilon
            && !((0.0..=1.0).contains(&apex.epsilon) && apex.alpha >= 0.0)
        {
            bail!("apex_epsilon: epsilon must be in [0, 1] and alpha >= 0");
        }
        Ok(())
    }

    /// Actor `index`'s exploration rate after it took `actions` actions.
    pub fn epsilon(&self, index: u32, actions: u64) -> f32 {
        match &self.apex_epsilon {
            Some(apex) => apex.for_actor(index, self.actors),
            None => self.policy.epsilon(actions),
        }
    }

    /// The policy's mode in this stage.
    pub fn mode(&self) -> policy::Mode {
        if self.stage == 1 {
            policy::Mode::GraspOnly
        } else {
            policy::Mode::PushGrasp
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn apex_rates_run_from_epsilon_to_epsilon_to_the_1_plus_alpha() {
        let apex = ApexEpsilon {
            epsilon: 0.4,
            alpha: 7.0,
        };
        assert!((apex.for_actor(0, 8) - 0.4).abs() < 1e-6);
        assert!((apex.for_actor(7, 8) - 0.4f32.powi(8)).abs() < 1e-7);
        assert!((apex.for_actor(0, 1) - 0.4).abs() < 1e-6);
        let middle = apex.for_actor(3, 8);
        assert!(middle < 0.4 && middle > 0.4f32.powi(8));
    }

    #[test]
    fn row_scenes_are_drawn_at_their_share_and_checked() {
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(5);
        let rows = RowScenes {
            share: 0.25,
            objects: 4,
            lines: 2,
        };
        let pack = Rows {
            blocks: 4,
            lines: 2,
        };
        let drawn: Vec<Rows> = (0..4000).map(|_| rows.draw(&mut rng)).collect();
        assert!(drawn.iter().all(|&n| n == Rows::NONE || n == pack));
        let share = drawn.iter().filter(|&&n| n == pack).count() as f64 / 4000.0;
        assert!((share - 0.25).abs() < 0.03, "{share}");

        let stage1 = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/stage1.toml");
        let text = std::fs::read_to_string(stage1).unwrap();
        let with = |rows: &str| RunConfig::parse(&format!("{text}\n[rows]\n{rows}"), "run.toml");
        with("share = 0.3\nobjects = 4").unwrap();
        let err = with("share = 1.5").unwrap_err().to_string();
        assert!(
            err.contains("run.toml") && err.contains("rows.share"),
            "{err}"
        );
        let err = with("share = 0.3\nobjects = 9").unwrap_err().to_string();
        assert!(err.contains("rows.objects"), "{err}");
        let err = with("share = 0.3\nobjects = 3\nlines = 4")
            .unwrap_err()
            .to_string();
        assert!(err.contains("rows.lines"), "{err}");
    }

    #[test]
    fn grasp_trials_are_refused_where_the_grasp_net_is_frozen() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        let with_trials = |stage: u8| {
            let text = std::fs::read_to_string(dir.join(format!("stage{stage}.toml"))).unwrap();
            let mut table: toml::Table = toml::from_str(&text).unwrap();
            table.insert("grasp_trials".into(), 2.into());
            RunConfig::parse(&toml::to_string(&table).unwrap(), "run.toml")
        };
        assert_eq!(with_trials(1).unwrap().grasp_trials, 2);
        assert_eq!(with_trials(3).unwrap().grasp_trials, 2);
        let err = with_trials(2).unwrap_err().to_string();
        assert!(
            err.contains("run.toml") && err.contains("grasp_trials"),
            "{err}"
        );
    }

    #[test]
    fn a_field_out_of_its_part_s_range_is_refused_naming_the_file_and_the_field() {
        let stage1 = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/stage1.toml");
        let text = std::fs::read_to_string(stage1).unwrap();
        // `field` is `table.key`; the error must name it (a nested table's key after it).
        let with = |field: &str, value: &str| {
            let (table, key) = field.split_once('.').unwrap();
            let mut config: toml::Table = toml::from_str(&text).unwrap();
            let value: toml::Table = toml::from_str(&format!("v = {value}")).unwrap();
            config
                .entry(table)
                .or_insert_with(|| toml::Table::new().into())
                .as_table_mut()
                .unwrap()
                .insert(key.into(), value["v"].clone());
            RunConfig::parse(&toml::to_string(&config).unwrap(), "run.toml")
        };
        for (field, value) in [
            ("sim.physics_hz", "0.0"),
            ("sim.grasp_lift", "0.03"),
            ("sim.drop_square", "1.0"),
            ("policy.q_star", "nan"),
            ("policy.grasp_margin", "-0.004"),
            ("policy.epsilon_start", "3.0"),
            ("policy.epsilon_decay", "1.5"),
            ("net.trunk_widths", "[]"),
            ("net.context_dilations", "[1, 0]"),
            ("net.head_width", "0"),
            ("learning.learning_rate", "-1.0"),
            ("learning.lr_decay", "{ to = 0.0, over_updates = 10 }"),
            ("learning.beta_1", "1.5"),
            ("learning.gamma", "1.0"),
            ("learning.huber_delta", "0.0"),
            ("learning.polyak_rate", "0.0"),
            ("buffer.capacity", "0"),
            ("buffer.samples_per_insert", "0.0"),
        ] {
            let err = with(field, value).unwrap_err().to_string();
            assert!(err.starts_with(&format!("run.toml: {field}")), "{err}");
        }
        // The edge of each range is accepted.
        for (field, value) in [
            ("sim.grasp_lift", "0.05"),
            ("policy.epsilon_decay", "1.0"),
            ("learning.gamma", "0.0"),
            ("learning.polyak_rate", "1.0"),
        ] {
            with(field, value).unwrap();
        }
    }

    #[test]
    fn the_shipped_stage_configs_are_valid_and_train_their_stage() {
        for (stage, mode, nets) in [
            (1, policy::Mode::GraspOnly, &[TrainedNet::Grasp][..]),
            (2, policy::Mode::PushGrasp, &[TrainedNet::Push][..]),
            (
                3,
                policy::Mode::PushGrasp,
                &[TrainedNet::Grasp, TrainedNet::Push][..],
            ),
        ] {
            let path =
                Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../configs/stage{stage}.toml"));
            let config = RunConfig::load(&path).unwrap();
            assert_eq!(config.stage, stage);
            assert_eq!(config.mode(), mode);
            assert_eq!(config.trained_nets(), nets);
            assert_eq!(config.init_from, None);
        }
    }
}
