//! The reports a run's roles write into its directory when they stop (`reports/`), and what
//! the launcher keeps of its processes and their faults: each written by the role that did
//! the work, read back into the run's summary and by any tool that reads a run.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Goal grasp success is reported over this many most recent attempts (the paper's metric).
pub const SUCCESS_WINDOW: usize = 30;

/// What an actor did, written to the run directory when it stops.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ActorReport {
    pub actor: u32,
    pub incarnation: u32,
    pub episodes: u64,
    pub actions: u64,
    /// Steps shipped to the buffer (episode ends not counted).
    pub steps_sent: u64,
    pub goal_grasps: u64,
    /// Grasps tried on copies of the scene (`grasp_trials`), not counted in `actions`.
    #[serde(default)]
    pub trials: u64,
    pub weights_version: u64,
    /// Seconds from the first weights received to the stop: the time `actions` took.
    pub acting_s: f64,
    /// CPU seconds the actor's process used over `acting_s`, all its threads, split evenly
    /// among its environments (none for an actor in a thread of the launcher, whose process
    /// the other roles share).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_s: Option<f64>,
    /// The peak resident memory of the actor's process in MB, split evenly among its
    /// environments (none in a thread of the launcher).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak_rss_mb: Option<f64>,
}

/// What one actor incarnation's stream delivered.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StreamCount {
    pub actor: u32,
    pub incarnation: u32,
    /// Steps received (episode ends not counted).
    pub steps: u64,
    /// The next sequence number expected.
    pub next_seq: u64,
    /// Sequence numbers that never arrived, unexplained (a lossless transport has none).
    pub missing: u64,
    /// Sequence numbers lost when the buffer restarted: received by the buffer that died
    /// after its last snapshot, or in flight to it.
    #[serde(default)]
    pub lost_in_restart: u64,
}

/// The buffer's counters: kept beside the replay snapshot and written as its report.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BufferReport {
    pub steps_received: u64,
    pub episodes: u64,
    pub goal_grasps: u64,
    /// Trial grasps' ends (`grasp_trials`): stored and relabelled, not counted in `episodes`.
    #[serde(default)]
    pub trials: u64,
    /// Goal grasp success over the run's first and last 30 episodes.
    pub success_first30: Option<f64>,
    pub success_last30: Option<f64>,
    pub streams: Vec<StreamCount>,
    /// Every stream's `lost_in_restart`, summed.
    #[serde(default)]
    pub lost_in_restarts: u64,
    /// Per restarted buffer incarnation: the messages lost when it took over (the sum of the
    /// gaps before each stream's first message to it).
    #[serde(default)]
    pub restart_losses: BTreeMap<u32, u64>,
    pub inserted: u64,
    pub relabelled: u64,
    pub sampled: u64,
    pub priority_updates: u64,
    pub snapshots: u64,
    /// The longest a snapshot held the buffer up: the copy it writes in the background
    /// (or, on request and at the end, the whole write).
    #[serde(default)]
    pub snapshot_hold_ms_max: f64,
}

impl BufferReport {
    /// Messages that never arrived, unexplained (not lost to a restart of the buffer).
    pub fn lost(&self) -> u64 {
        self.streams.iter().map(|s| s.missing).sum()
    }

    /// Steps that `actors` (the reports of actors that stopped cleanly) sent and this buffer
    /// never received: the lost end of a stream, which no gap in its sequence numbers shows.
    /// None when this report has no per-stream counts (a dead buffer's last status). Only
    /// for a buffer that was never restarted: a restart loses messages it counts apart.
    pub fn unreceived(&self, actors: &[ActorReport]) -> u64 {
        if self.streams.is_empty() && self.steps_received > 0 {
            return 0;
        }
        actors
            .iter()
            .map(|actor| {
                let received = self
                    .streams
                    .iter()
                    .find(|s| s.actor == actor.actor && s.incarnation == actor.incarnation)
                    .map_or(0, |s| s.steps);
                actor.steps_sent.saturating_sub(received)
            })
            .sum()
    }
}

/// What the learner did, written to the run directory when it stops.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LearnerReport {
    /// Updates in the whole run (a resumed run counts on from its checkpoint).
    pub updates: u64,
    pub weights_version: u64,
    pub checkpoints: u64,
    pub last_loss: Option<f32>,
    /// Updates this process took and the seconds from its first batch to the stop.
    pub session_updates: u64,
    pub training_s: f64,
    /// Seconds of `training_s` spent on updates: the step, sending its priorities,
    /// publishing and checkpointing. The rest the learner waited for batches, which the
    /// buffer holds back while the actors have not caught up (the rate limiter). Near
    /// `training_s`, the learner set the run's pace; `session_updates / busy_s` is its own,
    /// whatever the actors do.
    #[serde(default)]
    pub busy_s: f64,
    /// Of `busy_s`, the training steps (`Trainer::train_step`: the batch to the nets' device,
    /// the forward pass, the read of its values). On a GPU backend the backward pass and the
    /// optimiser may still be running when it returns; the next read waits for them, which
    /// is then the publication's.
    #[serde(default)]
    pub step_s: f64,
    /// Of `busy_s`, publishing the weights (reading them off the nets' device, sending them).
    #[serde(default)]
    pub publish_s: f64,
    /// Of `busy_s`, writing checkpoints. The rest of `busy_s` unpacks each batch, values its
    /// next states where the learner does, logs the update and sends the priorities.
    #[serde(default)]
    pub checkpoint_s: f64,
    /// CPU seconds the learner's process used over `training_s`, all its threads (none for a
    /// learner in a thread of the launcher, whose process the other roles share).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_s: Option<f64>,
    /// Requests the buffer answered with no items (none of their primitive stored yet).
    #[serde(default)]
    pub empty_batches: u64,
    /// Batches answering a dead predecessor's requests, or requests given up when the
    /// buffer restarted, skipped.
    #[serde(default)]
    pub stale_batches: u64,
    /// Updates a dead predecessor took after the checkpoint this learner resumed from,
    /// taken again (its weight versions were published; these updates are not in the nets).
    #[serde(default)]
    pub redone_updates: u64,
    /// Next states this process valued itself (`learning.target_update_every`), not taking
    /// their actors' values.
    #[serde(default)]
    pub learned_next_values: u64,
    /// Seconds this process spent warming up before its first batch: tuning its kernels on
    /// a GPU backend, none on the CPU's (`learner::Trainer::warm_up`).
    #[serde(default)]
    pub warm_up_s: f64,
}

impl LearnerReport {
    /// This process's updates per second from its first batch to the stop.
    pub fn updates_per_s(&self) -> Option<f64> {
        (self.training_s > 0.0).then(|| self.session_updates as f64 / self.training_s)
    }

    /// The share of that time it spent on updates rather than waiting for batches.
    pub fn busy_share(&self) -> Option<f64> {
        (self.training_s > 0.0).then(|| (self.busy_s / self.training_s).min(1.0))
    }

    /// Its updates per second of updating: its own pace, whether the actors kept up or not.
    pub fn updates_per_busy_s(&self) -> Option<f64> {
        (self.busy_s > 0.0).then(|| self.session_updates as f64 / self.busy_s)
    }
}

/// A role that failed during a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Fault {
    /// The role's name (`actor-0-1`, `learner`, ...).
    pub role: String,
    /// Seconds from the launcher's start to when it noticed.
    pub at_s: f64,
    pub cause: String,
    /// Whether it was started again and the run went on (a joined host: it came back).
    pub restarted: bool,
    /// For an actor: the messages of its stream that never reached the buffer (filled in
    /// from the buffer's counts when the run ends).
    #[serde(default)]
    pub lost_messages: Option<u64>,
}

/// The processes file: which process plays which role (for users and tests).
#[derive(Serialize, Deserialize)]
pub struct ProcessEntry {
    pub role: String,
    pub pid: u32,
}

/// What a joined host did (`reports/host.json` in its directory).
#[derive(Debug, Serialize)]
pub struct HostSummary {
    pub run_id: String,
    pub host: String,
    pub first_actor: u32,
    pub actors: u32,
    pub incarnation: u32,
    /// Steps and episode ends sent to the central host.
    pub messages_sent: u64,
    pub parcels_sent: u64,
    /// Parcels sent again because the link dropped before the central host took them.
    pub parcels_resent: u64,
    /// Bytes before and after compression.
    pub raw_bytes: u64,
    pub sent_bytes: u64,
    /// Messages thrown away because the central host was gone for good.
    pub abandoned: u64,
    pub actor_restarts: u32,
    /// Its actors that failed (crashed, or hung and killed), in order.
    pub faults: Vec<Fault>,
    /// Why it stopped.
    pub ended: String,
}

/// A joined host as the run records it (`hosts.json`, and the run's summary).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HostReport {
    pub host: String,
    /// Its actors' environments are indices `first_actor..first_actor + actors` (one per
    /// actor process unless the run's `envs_per_actor` says more).
    pub first_actor: u32,
    pub actors: u32,
    /// Times it joined (1 for a host that never left).
    pub joins: u32,
    /// Whether its session is present now.
    pub alive: bool,
    /// Whether it said it had sent all it will (at the run's stop).
    pub done: bool,
    /// Times its session was lost (killed, or its link dropped past Zenoh's lease).
    pub lost_links: u32,
    pub steps_received: u64,
    pub episode_ends_received: u64,
    /// Messages refused: not a step or an episode end, of an actor not its own, damaged.
    pub rejected: u64,
    /// Steps its actors reported sent that never arrived (a host that died mid-send).
    pub lost_in_flight: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sent(actor: u32, incarnation: u32, steps_sent: u64) -> ActorReport {
        ActorReport {
            actor,
            incarnation,
            steps_sent,
            ..ActorReport::default()
        }
    }

    fn stream(actor: u32, incarnation: u32, steps: u64) -> StreamCount {
        StreamCount {
            actor,
            incarnation,
            steps,
            next_seq: steps,
            ..StreamCount::default()
        }
    }

    #[test]
    fn steps_missing_at_the_end_of_a_stream_are_unreceived() {
        let report = BufferReport {
            steps_received: 7,
            streams: vec![stream(0, 0, 4), stream(1, 1, 3)],
            ..BufferReport::default()
        };
        assert_eq!(report.lost(), 0, "no gap");
        assert_eq!(report.unreceived(&[sent(0, 0, 4), sent(1, 1, 3)]), 0);
        // Actor 1's last step, and the only one of an actor whose stream never opened.
        let actors = [sent(0, 0, 4), sent(1, 1, 4), sent(2, 0, 1)];
        assert_eq!(report.unreceived(&actors), 2);
        // A dead buffer's last status has no per-stream counts: nothing can be said.
        let from_status = BufferReport {
            steps_received: 7,
            ..BufferReport::default()
        };
        assert_eq!(from_status.unreceived(&actors), 0);
    }
}
