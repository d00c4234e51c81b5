//! The messages of a run, and who sends each. Steps flow actor -> buffer -> learner; only
//! priorities, weights and control flow back.

use experience::{BatchItem, Key, StoredTransition, Transition};
use serde::{Deserialize, Serialize};
use sim::{ObjectId, Primitive};

/// Everything that travels between the roles of a run.
// A message is made for one send and read once, never kept in bulk: a boxed step would cost
// an allocation per step and save nothing.
#[expect(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Message {
    Step(Step),
    EpisodeEnd(EpisodeEnd),
    SampleRequest(SampleRequest),
    Batch(BatchMessage),
    PriorityUpdate(PriorityUpdate),
    Weights(Weights),
    Control(Control),
    Status(Status),
    /// The buffer (this incarnation) has started and takes sample requests from now on; any
    /// sent before were lost with its predecessor (buffer -> learner, on the batches topic).
    BufferStarted(u32),
}

/// The roles of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Role {
    Actor,
    Buffer,
    Learner,
}

impl Role {
    pub const ALL: [Role; 3] = [Role::Actor, Role::Buffer, Role::Learner];

    /// The role's name, the one place roles are named (command lines, logs, files).
    pub fn name(self) -> &'static str {
        match self {
            Role::Actor => "actor",
            Role::Buffer => "buffer",
            Role::Learner => "learner",
        }
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Role {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, String> {
        Role::ALL
            .into_iter()
            .find(|role| role.name() == name)
            .ok_or_else(|| format!("{name:?} is not a role (actor, buffer or learner)"))
    }
}

/// Who sent a message on the steps topic, and its place in that sender's stream: `seq`
/// counts every step and episode end an actor incarnation sent, from 0, so the buffer can
/// prove that nothing was lost.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Origin {
    pub actor: u32,
    /// How many times this actor index was started before (0 for the first process).
    pub incarnation: u32,
    pub seq: u64,
}

/// One action of an episode (actor -> buffer).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Step {
    pub origin: Origin,
    /// The observation, goal, action, reward, grasped object and bootstrap value.
    pub transition: Transition,
    /// The actor's initial priority, |label - predicted Q| (Ape-X).
    pub priority: f64,
    /// Q at the executed pixel when the action was chosen.
    pub predicted_q: f32,
    /// Whether the pixel and rotation were explored rather than the argmax.
    pub explored: bool,
    /// The weight version the action was chosen with.
    pub weights_version: u64,
}

/// The end of an episode (actor -> buffer): its steps are complete and may be relabelled.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeEnd {
    pub origin: Origin,
    pub episode: u64,
    pub goal: ObjectId,
    /// The object the episode's grasp picked, if any.
    pub grasped: Option<ObjectId>,
    /// Steps sent for the episode (pushes and the grasp).
    pub steps: u32,
    /// A grasp tried on a copy of the scene (`grasp_trials`): stored and relabelled as an
    /// episode, but not counted as one. Absent from logs written before trials: false.
    #[serde(default)]
    pub trial: bool,
}

impl EpisodeEnd {
    /// Whether the goal itself was grasped (the paper's goal grasp success).
    pub fn goal_grasped(&self) -> bool {
        self.grasped == Some(self.goal)
    }
}

/// The learner asks for a batch (learner -> buffer).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SampleRequest {
    /// Echoed in the answering batch.
    pub id: u64,
    pub primitive: Primitive,
    pub size: u32,
}

/// The buffer's answer to a [`SampleRequest`] (buffer -> learner): the items as the buffer
/// stores them, observations packed; the learner unpacks them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BatchMessage {
    pub request: u64,
    pub items: Vec<BatchItem<StoredTransition>>,
}

/// New priorities for sampled items (learner -> buffer).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PriorityUpdate {
    pub updates: Vec<(Key, f64)>,
}

/// The nets' parameters (learner -> actors); late joiners get the latest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Weights {
    /// The learner updates these weights come from (0: the initial weights); it continues
    /// across `--resume`, so it only grows within a run.
    pub version: u64,
    pub stage: u8,
    /// Both nets, as `qnet::QNets::to_bytes` writes them.
    pub bytes: Vec<u8>,
}

/// Orders from the launcher.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Control {
    /// The addressed role finishes what it is doing, saves what it must, and exits.
    Stop(Role),
    /// The buffer writes a snapshot now.
    Snapshot,
}

/// Progress reports (every role -> launcher). Counters are cumulative, so a report that the
/// launcher misses loses nothing: the next one says it all.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Status {
    Actor {
        actor: u32,
        incarnation: u32,
        episodes: u64,
        /// Steps this incarnation sent.
        steps_sent: u64,
        weights_version: u64,
    },
    Buffer {
        /// Steps received from every actor, in every incarnation.
        steps_received: u64,
        /// Episodes ended (the run's episode budget counts these).
        episodes: u64,
        /// Goal grasp success over the last 30 grasp attempts of the whole run.
        success_last30: Option<f64>,
        /// Items stored, relabelled copies included, and how many are stored now.
        inserted: u64,
        stored: u64,
        capacity: u64,
        relabelled: u64,
        /// Messages missing from some actor's stream (never expected: lossless transport).
        lost: u64,
    },
    Learner {
        updates: u64,
        weights_version: u64,
        loss: Option<f32>,
    },
    /// A role is tuning its GPU kernels before it starts work (CubeCL's autotune, seconds
    /// on a GPU, minutes on a software device): alive, though it sends nothing else yet.
    Tuning { role: Role },
    /// A role could not go on; the launcher stops the run with this message.
    Failed { role: Role, error: String },
    /// A role goes on, but the person running it should know (the launcher prints it): it
    /// started from a previous generation of its saved state, the newest being damaged.
    Warning { role: Role, warning: String },
}
