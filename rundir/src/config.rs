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

use crate::backend::Backends;
use crate::layout::ProcessLayout;

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
    /// The share of episodes whose goal is the object seen with the most occupied border
    /// ring ([`sim::measure::most_crowded`]); the rest draw the goal among the objects seen
    /// at random. The paper's test goals sit in packed clusters, random drops' mostly do
    /// not. 0 (the paper): every goal at random.
    #[serde(default)]
    pub crowded_goals: f64,
    /// Goals only among the objects seen whose centre lies over the workspace. An object
    /// pushed past the workspace's edge rests on the floor there, partly seen, where a grasp
    /// can hardly reach it and no push brings it back; the original's training goals are
    /// objects of a fresh central drop (its scene restarts once the goal has left). false:
    /// any object seen.
    #[serde(default)]
    pub goals_over_workspace: bool,
    /// A scene keeps its first episode's goal: the episodes after a failed grasp take the
    /// same goal again, and the scene is dropped anew once the goal has left the view
    /// (grasped, or pushed out), as the original's training does (`main.py`: a fixed goal
    /// index; the scene restarts once the goal has left). Every goal is then an object of
    /// a fresh drop, as the test cases' are; the goal's leaving does not end the chain of
    /// labels (the last step bootstraps on the fresh drop's first decision). false: each
    /// episode draws its goal among the objects seen, and the scene thins out over its
    /// episodes until empty.
    #[serde(default)]
    pub goal_per_scene: bool,
    /// Before each grasp it executes, an actor tries this many other grasps of the goal
    /// (pixels and angles drawn as exploration draws them) on exact copies of the scene and
    /// ships each as an experience of its own: denser grasp labels per scene, which only a
    /// simulator can give. 0: the paper's one grasp per episode.
    #[serde(default)]
    pub grasp_trials: usize,
    /// A push that takes the goal out of view ends its episode as a failure: the push is
    /// labelled with its reward alone (a push that loses the goal changes nothing around it:
    /// -0.5 under the dense reward). Otherwise (the default) the episode goes on without its
    /// goal, and the push bootstraps on the next state's value, read over every object's
    /// pixels once the goal is gone.
    #[serde(default)]
    pub goal_lost_ends_episode: bool,
    /// Actor processes when `--actors` is not given.
    pub actors: u32,
    /// Environments each actor process steps (Sample Factory's workers), their decisions'
    /// inference one batch: process `i` plays environments `i * envs_per_actor ..`, each
    /// with its own seed, exploration, episodes and stream of steps, as an actor process of
    /// its own would.
    #[serde(default = "one_environment")]
    pub envs_per_actor: u32,
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
    /// Ape-X exploration instead of the policy's decaying schedule: environment i of N
    /// (every actor process's, here and on joined hosts) explores with a fixed
    /// epsilon^(1 + alpha i / (N - 1)).
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
    #[serde(default)]
    pub run: Supervision,
    /// Which backend runs the learner's nets and the actors' (`cpu` or `wgpu`).
    #[serde(default)]
    pub backend: Backends,
}

/// How the launcher watches its roles.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Supervision {
    /// A role process that sends no status report for this long is taken to be hung, killed
    /// and handled as a crash. The buffer and the learner report four times a second and an
    /// actor once an episode; long enough for a checkpoint or a snapshot to be written.
    pub heartbeat_timeout_s: f64,
    /// Actors expected on joined hosts (`train --listen`, `join`), beside the central host's
    /// `actors`: Ape-X's exploration rates spread over all of them.
    pub remote_actors: u32,
}

impl Default for Supervision {
    fn default() -> Self {
        Self {
            heartbeat_timeout_s: 30.0,
            remote_actors: 0,
        }
    }
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
    /// A process's log goes on in a new file (`<role>.1.mcap`, `<role>.2.mcap`, ...) every
    /// this many minutes (0: one file), which bounds both each file and the index its writer
    /// holds in memory until the file ends.
    pub segment_minutes: f64,
}

impl Default for LoggingConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            image_every: 10,
            segment_minutes: 60.0,
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
    /// The fixed exploration rate of actor `index` of `actors` (an index past the last, an
    /// actor of a host that joined unannounced, explores as the last).
    pub fn for_actor(&self, index: u32, actors: u32) -> f32 {
        let spread = if actors > 1 {
            (f64::from(index) / f64::from(actors - 1)).min(1.0)
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
        if !(self.run.heartbeat_timeout_s.is_finite() && self.run.heartbeat_timeout_s > 0.0) {
            bail!(
                "run.heartbeat_timeout_s: {} is not a positive number of seconds",
                self.run.heartbeat_timeout_s
            );
        }
        if self.objects == 0 {
            bail!("objects: must be at least 1");
        }
        if !(0.0..=1.0).contains(&self.rows.share) {
            bail!("rows.share: {} is not in [0, 1]", self.rows.share);
        }
        if !(0.0..=1.0).contains(&self.crowded_goals) {
            bail!("crowded_goals: {} is not in [0, 1]", self.crowded_goals);
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
        if self.envs_per_actor == 0 {
            bail!("envs_per_actor: must be at least 1");
        }
        let segment = self.logging.segment_minutes;
        if !(segment.is_finite() && segment >= 0.0) {
            bail!("logging.segment_minutes: {segment} is not 0 (one file) or a number of minutes");
        }
        if self.actors == 0 && self.run.remote_actors == 0 {
            bail!("actors: must be at least 1 (0 only with run.remote_actors on joined hosts)");
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

    /// Sizes the replay for this run: a capacity in bytes becomes transitions per ring at
    /// the bytes a stored step of this run's scenes takes, and a replay that cannot fit the
    /// memory this machine has available is refused, with the figure it would need. Returns
    /// the bytes the full replay takes.
    pub fn size_buffer(&mut self) -> Result<u64> {
        let step = buffer::bytes_per_step(&self.sim, self.objects)?;
        let asked = self.buffer.capacity;
        self.buffer.resolve(step);
        let slots = self.buffer.slots()?;
        let needed = 2 * slots as u64 * step as u64;
        if let Some(available) = available_memory()
            && needed > available
        {
            bail!(
                "buffer.capacity = {asked}: {slots} transitions per ring need about {:.1} GB \
                 (2 rings x {slots} x ~{step} bytes a stored step at {side} x {side}), more \
                 than the {:.1} GB this machine has available; lower it, or give it in bytes \
                 (capacity = \"8 GiB\")",
                needed as f64 / 1e9,
                available as f64 / 1e9,
                side = self.side(),
            );
        }
        Ok(needed)
    }

    /// The environments of the run's actors, here and on joined hosts.
    pub fn environments(&self) -> u32 {
        self.layout()
            .environments(self.actors + self.run.remote_actors)
    }

    /// How the run's environments fall into actor processes.
    pub fn layout(&self) -> ProcessLayout {
        ProcessLayout::new(self.envs_per_actor)
    }

    /// Environment `index`'s exploration rate after it took `actions` actions.
    pub fn epsilon(&self, index: u32, actions: u64) -> f32 {
        match &self.apex_epsilon {
            Some(apex) => apex.for_actor(index, self.environments()),
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

pub(crate) fn one_environment() -> u32 {
    1
}

/// The memory this machine has available now (Linux's MemAvailable), where it says.
pub fn available_memory() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
