//! What the roles write to their MCAP logs (`logs/<run-id>/<role>.mcap`): the topics and the
//! JSON records on them, shared by the writers and by `pushgrasp inspect`.

use serde::{Deserialize, Serialize};

/// Every shipped step (actor): its action, prediction, reward and priority.
pub const ACTOR_STEP: &str = "/actor/step";
/// Every finished episode (actor).
pub const ACTOR_EPISODE: &str = "/actor/episode";
/// What the actor saw at each step of every `logging.image_every`-th episode, all stamped
/// with the step's `pictures_ns`: colour (rgb8), height (mono16, tenths of a millimetre), the
/// best grasp and push Q over the rotations (mono8, hundredths: 0..2.55; push only where the
/// stage pushes), and the objects as boxes (`foxglove.SceneUpdate`).
pub const ACTOR_COLOUR: &str = "/actor/colour";
pub const ACTOR_HEIGHT: &str = "/actor/height";
pub const ACTOR_GRASP_Q: &str = "/actor/grasp_q";
pub const ACTOR_PUSH_Q: &str = "/actor/push_q";
pub const ACTOR_SCENE: &str = "/actor/scene";
/// The picture topics, in the order an episode export names its files.
pub const ACTOR_PICTURES: [&str; 4] = [ACTOR_COLOUR, ACTOR_HEIGHT, ACTOR_GRASP_Q, ACTOR_PUSH_Q];
/// Every episode end the buffer took in.
pub const BUFFER_EPISODE: &str = "/buffer/episode";
/// The buffer's counters, a few times a second.
pub const BUFFER_STATS: &str = "/buffer/stats";
/// Every learner update.
pub const LEARNER_UPDATE: &str = "/learner/update";
/// The launcher's view of the run, once a second.
pub const LAUNCHER_PROGRESS: &str = "/launcher/progress";
/// Every process's memory (`memory::MemoryRecord`), every `memory::MEMORY_EVERY`: each role
/// process's own log, and the launcher's.
pub const PROCESS_MEMORY: &str = "/process/memory";
/// The run's summary (as `summary.json`), when it ends.
pub const LAUNCHER_SUMMARY: &str = "/launcher/summary";

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepRecord {
    pub actor: u32,
    pub incarnation: u32,
    pub episode: u64,
    pub step: u32,
    pub goal: u8,
    pub primitive: String,
    pub rotation: u8,
    pub angle_deg: f32,
    pub row: usize,
    pub col: usize,
    pub predicted_q: f32,
    pub goal_grasp_q: f32,
    pub explored: bool,
    pub reason: String,
    pub reward: f32,
    pub grasped: Option<u8>,
    pub priority: f64,
    pub weights_version: u64,
    /// When this step's pictures were logged (their log time), if they were.
    pub pictures_ns: Option<u64>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeRecord {
    pub actor: u32,
    pub incarnation: u32,
    pub episode: u64,
    pub scene_seed: u64,
    pub goal: u8,
    pub grasped: Option<u8>,
    pub goal_grasped: bool,
    pub steps: u32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UpdateRecord {
    pub updates: u64,
    pub primitive: String,
    pub batch: usize,
    pub loss: f32,
    pub mean_predicted_q: f32,
    pub mean_td_error: f32,
}
